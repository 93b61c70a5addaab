//! Rendering speed of the synthetic scene generator: one frame (2×2 anti-aliasing, full camera
//! response; realistic style: with blur and JPEG) at the sizes training uses. `cargo bench -p densefeat-benches --bench synth`.

use criterion::{criterion_group, criterion_main, Criterion};
use densefeat::synth::{Scene, SceneConfig, Style};

fn render(c: &mut Criterion) {
    for (style, w, h) in [
        (Style::Classic, 320, 240),
        (Style::Classic, 640, 480),
        (Style::Real, 320, 240),
        (Style::Real, 640, 480),
    ] {
        let cfg = SceneConfig { width: w, height: h, style, seed: 100_000, ..SceneConfig::default() };
        let scene = Scene::generate(&cfg).expect("config is valid");
        let name = match style {
            Style::Classic => format!("cpu_synth_render_{w}x{h}"),
            _ => format!("cpu_synth_render_{style}_{w}x{h}"),
        };
        c.bench_function(&name, |b| {
            let mut i = 0;
            b.iter(|| {
                i = (i + 1) % scene.frames();
                scene.render(i).expect("frame index is in range")
            })
        });
    }
}

criterion_group! {
    name = benches;
    config = Criterion::default().sample_size(20);
    targets = render
}
criterion_main!(benches);
