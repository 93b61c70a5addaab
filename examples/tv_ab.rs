// Throwaway A/B harness (not committed): thread CPU time of the fused vs reference iteration parts.
use densefeat::cli::bench_tv::{tv_inputs, TvInputs};
use densefeat::dtam::*;

fn cpu() -> f64 {
    let mut t = libc::timespec { tv_sec: 0, tv_nsec: 0 };
    unsafe { libc::clock_gettime(libc::CLOCK_THREAD_CPUTIME_ID, &mut t) };
    t.tv_sec as f64 * 1e3 + t.tv_nsec as f64 / 1e6
}
fn med(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn main() {
    let args: Vec<String> = std::env::args().collect();
    let (w, h, k): (usize, usize, usize) =
        (args[1].parse().unwrap(), args[2].parse().unwrap(), args[3].parse().unwrap());
    let theta_scale: f64 = args.get(4).map(|s| s.parse().unwrap()).unwrap_or(1.0);
    let solves: usize = args.get(5).map(|s| s.parse().unwrap()).unwrap_or(0);
    let pool = rayon::ThreadPoolBuilder::new().num_threads(1).build().unwrap();
    pool.install(|| {
        let TvInputs { costs, bins, grey, init } = tv_inputs(w, h, k).unwrap();
        let p = DtamParams::default();
        let g = edge_weights(grey.view(), p.alpha, p.beta);
        let range = CostRange::new(costs.view());
        let theta = p.theta_start * theta_scale;
        let mut tv = HuberTv::new(init.clone(), g.clone(), p.epsilon);
        let mut tr = HuberTv::new(init.clone(), g.clone(), p.epsilon);
        let mut a = init.clone();
        let mut ar = init.clone();
        let mut t: [Vec<f64>; 7] = Default::default();
        if std::env::var("ONLY_SOLVE").is_ok() {
            let c0 = cpu();
            let (_, rep) = solve(costs.view(), &bins, grey.view(), init.view(), &p).unwrap();
            println!("solve only: {:.0} ms, {} it", cpu() - c0, rep.iterations);
            return;
        }
        if std::env::var("ONLY_FUSED").is_ok() {
            tv.step(a.view(), theta);
            let c0 = cpu();
            for _ in 0..50 {
                std::hint::black_box(search_with_energy(costs.view(), &range, &bins, &tv, theta, p.lambda, &mut a, Dispatch::Auto));
            }
            println!("fused only: {:.2} ms", (cpu() - c0) / 50.0);
            return;
        }
        for run in 0..12 {
            let c0 = cpu();
            tv.step(a.view(), theta);
            let c1 = cpu();
            let m = search_with_energy(costs.view(), &range, &bins, &tv, theta, p.lambda, &mut a, Dispatch::Auto);
            let c2 = cpu();
            std::hint::black_box(exhaustive_search(costs.view(), &range, &bins, tv.primal(), theta, p.lambda));
            let c3 = cpu();
            tr.step_reference(ar.view(), theta);
            let c4 = cpu();
            ar = exhaustive_search_reference(costs.view(), &range, &bins, tr.primal(), theta, p.lambda);
            let c5 = cpu();
            let e = total_energy(&tr, costs.view(), &bins, ar.view(), theta, p.lambda);
            let gg = rms_gap(tr.primal(), ar.view());
            let c6 = cpu();
            assert_eq!(e.to_bits(), m.energy.to_bits());
            assert_eq!(gg.to_bits(), m.gap.to_bits());
            if run >= 2 {
                for (i, v) in [c1 - c0, c2 - c1, c3 - c2, c4 - c3, c5 - c4, c6 - c5, 0.0].into_iter().enumerate() { t[i].push(v); }
            }
        }
        let [s, f, sa, rs, rse, ren, _] = t.map(med);
        println!("{w}x{h} K={k} θx{theta_scale}: NEW step {s:.2} fused {f:.2} (search alone {sa:.2}) = {:.2} | REF step {rs:.2} search {rse:.2} energy+gap {ren:.2} = {:.2} ms CPU", s + f, rs + rse + ren);
        for _ in 0..solves {
            let c0 = cpu();
            let (_, rep) = solve(costs.view(), &bins, grey.view(), init.view(), &p).unwrap();
            let c1 = cpu();
            let (_, rep2) = solve_reference(costs.view(), &bins, grey.view(), init.view(), &p).unwrap();
            let c2 = cpu();
            assert_eq!(rep.energy, rep2.energy);
            println!("  solve: NEW {:.0} ms ({} it, {:.2}/it) REF {:.0} ms ({:.2}/it) CPU", c1 - c0, rep.iterations, (c1 - c0) / rep.iterations as f64, c2 - c1, (c2 - c1) / rep2.iterations as f64);
        }
    });
}
