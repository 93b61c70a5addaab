//! The network's commands: `init-weights` reproduces the shipped file byte for byte, `features`
//! writes a valid `.npy` (and a PCA picture), `bench` validates its arguments.

use std::path::PathBuf;
use std::process::Command;

use densefeat::io::npy_f32_header;

fn bin() -> Command {
    Command::new(env!("CARGO_BIN_EXE_densefeat"))
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

#[test]
fn init_weights_reproduces_the_shipped_file() {
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("w.safetensors");
    let status = bin()
        .args(["init-weights", "--seed", "0", "--mean-of-images"])
        .arg(root().join("fixtures/synthetic/room_s1/images"))
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    let shipped = std::fs::read(root().join("fixtures/weights/featurenet_init_seed0.safetensors")).unwrap();
    assert!(std::fs::read(&out).unwrap() == shipped, "regenerated weights differ from the shipped file");
}

#[test]
fn npy_header_is_numpy_v1_aligned_to_64() {
    let h = npy_f32_header(&[120, 160, 32]);
    assert_eq!(h.len() % 64, 0);
    assert_eq!(&h[..8], b"\x93NUMPY\x01\x00");
    assert_eq!(u16::from_le_bytes([h[8], h[9]]) as usize, h.len() - 10);
    let dict = std::str::from_utf8(&h[10..]).unwrap();
    assert!(
        dict.starts_with("{'descr': '<f4', 'fortran_order': False, 'shape': (120, 160, 32), }"),
        "{dict}"
    );
    assert!(dict.ends_with('\n'));
}

#[test]
fn features_writes_npy_and_viz() {
    let dir = tempfile::tempdir().unwrap();
    let (npy, png) = (dir.path().join("f.npy"), dir.path().join("f.png"));
    let out = bin()
        .arg("features")
        .arg(root().join("fixtures/synthetic/room_s1/images/00000.png"))
        .arg("--out")
        .arg(&npy)
        .arg("--viz")
        .arg(&png)
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let bytes = std::fs::read(&npy).unwrap();
    let (w, h) =
        densefeat::image::read_dimensions(&root().join("fixtures/synthetic/room_s1/images/00000.png"))
            .unwrap();
    let shape = [h.div_ceil(2), w.div_ceil(2), 32];
    let header = npy_f32_header(&shape);
    assert_eq!(&bytes[..header.len()], &header[..]);
    assert_eq!(bytes.len(), header.len() + 4 * shape.iter().product::<usize>());
    let values: Vec<f32> =
        bytes[header.len()..].chunks_exact(4).map(|b| f32::from_le_bytes(b.try_into().unwrap())).collect();
    assert!(values.iter().all(|v| v.is_finite()));
    assert!(values.iter().any(|&v| v != 0.0));
    assert_eq!(densefeat::image::read_dimensions(&png).unwrap(), (shape[1], shape[0]));
}

#[test]
fn features_default_weights_are_the_built_in_shipped_ones() {
    // Without --weights the shipped weights come from the binary, not from a source-tree path (an
    // installed binary has no source tree): same output as naming the shipped file, no path default.
    let dir = tempfile::tempdir().unwrap();
    let image = root().join("fixtures/synthetic/room_s1/images/00000.png");
    let run = |name: &str, weights: Option<PathBuf>| {
        let out_path = dir.path().join(name);
        let mut cmd = bin();
        cmd.current_dir(dir.path()).arg("features").arg(&image).arg("--out").arg(&out_path);
        if let Some(w) = weights {
            cmd.arg("--weights").arg(w);
        }
        let out = cmd.output().unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
        std::fs::read(out_path).unwrap()
    };
    let built_in = run("a.npy", None);
    let file = run("b.npy", Some(root().join("fixtures/weights/featurenet_trained_mf8sow.safetensors")));
    assert!(built_in == file, "built-in and file weights give different features");
    let help = bin().args(["features", "--help"]).output().unwrap();
    let help = String::from_utf8_lossy(&help.stdout);
    assert!(help.contains("built into the binary") && !help.contains("[default: /"), "{help}");
}

#[test]
fn features_with_bad_weights_names_the_file() {
    let dir = tempfile::tempdir().unwrap();
    let weights = dir.path().join("bad.safetensors");
    std::fs::write(&weights, b"nope").unwrap();
    let out = bin()
        .arg("features")
        .arg(root().join("fixtures/synthetic/room_s1/images/00000.png"))
        .arg("--weights")
        .arg(&weights)
        .arg("--out")
        .arg(dir.path().join("f.npy"))
        .output()
        .unwrap();
    assert_eq!(out.status.code(), Some(1));
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("bad.safetensors"), "{err}");
    assert!(!dir.path().join("f.npy").exists());
}

#[test]
fn bench_forward_requires_twenty_runs() {
    let out = bin().args(["bench", "forward", "--size", "16x16", "--runs", "3"]).output().unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("--runs"));
}

#[test]
fn bench_forward_names_the_kernels_it_runs() {
    let out = bin()
        .args(["bench", "forward", "--size", "32x32", "--runs", "20", "--gemm-size", "64"])
        .env("DENSEFEAT_NO_AVX512", "1")
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let stdout = String::from_utf8_lossy(&out.stdout);
    let line = stdout.lines().find(|l| l.starts_with("kernels (cpu backend")).expect("a kernels line");
    for kind in ["conv s2 3->32: ", "conv s1 32->32: ", "concat + conv s2 35->32: ", "deconv 5x5 s2 + add: "]
    {
        assert!(line.contains(kind), "{kind} missing from {line}");
    }
    // With AVX-512 switched off at run time no AVX-512 kernel is named.
    assert!(!line.contains("avx512"), "{line}");
}
