//! Process CPU time, so benchmarks can report how much of the machine they actually got.

/// User + system CPU time of this process from `/proc/self/stat` (Linux; 100 Hz ticks), or `None`.
pub fn process_cpu_seconds() -> Option<f64> {
    let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
    // Fields after the parenthesised command name: state is field 3, utime 14, stime 15.
    let rest = &stat[stat.rfind(')')? + 2..];
    let fields: Vec<&str> = rest.split_whitespace().collect();
    let utime: f64 = fields.get(11)?.parse().ok()?;
    let stime: f64 = fields.get(12)?.parse().ok()?;
    Some((utime + stime) / CLOCK_TICKS_PER_SECOND)
}

/// `sysconf(_SC_CLK_TCK)` on every Linux target we run on.
const CLOCK_TICKS_PER_SECOND: f64 = 100.0;
