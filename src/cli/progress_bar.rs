//! The terminal bar of `train` and `train-normals`: the library's [`Progress`] drawn with
//! indicatif on stderr.

use densefeat::progress::Progress;

/// A bar on stderr (or nothing when `visible` is false: `--quiet`).
pub struct Bar {
    bar: indicatif::ProgressBar,
    visible: bool,
}

impl Bar {
    /// A bar, hidden with `visible = false`.
    pub fn new(visible: bool) -> Self {
        Bar { bar: indicatif::ProgressBar::hidden(), visible }
    }
}

impl Progress for Bar {
    fn start(&mut self, total: u64, position: u64) {
        if self.visible {
            self.bar = indicatif::ProgressBar::new(total);
            if let Ok(style) = indicatif::ProgressStyle::with_template(
                "{bar:40} {pos}/{len} steps, {elapsed} elapsed, eta {eta} {msg}",
            ) {
                self.bar.set_style(style);
            }
        }
        self.bar.set_position(position);
    }

    fn update(&mut self, position: u64, message: &str) {
        if !message.is_empty() {
            self.bar.set_message(message.to_string());
        }
        self.bar.set_position(position);
    }

    fn line(&mut self, line: &str) {
        self.bar.println(line);
    }

    fn finish(&mut self) {
        self.bar.finish();
    }
}
