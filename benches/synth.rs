//! Rendering speed of the synthetic scene generator: one frame (2×2 anti-aliasing, full camera
//! response) at the sizes training uses. `cargo bench --bench synth`.

use criterion::{criterion_group, criterion_main, Criterion};
use densefeat::synth::{Scene, SceneConfig};

fn render(c: &mut Criterion) {
    for (w, h) in [(320, 240), (640, 480)] {
        let scene = Scene::generate(&SceneConfig { width: w, height: h, ..SceneConfig::default() })
            .expect("default config is valid");
        c.bench_function(&format!("cpu_synth_render_{w}x{h}"), |b| {
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
