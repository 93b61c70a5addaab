//! Feature-network weights (SPEC.md §8.3-8.6): PyTorch names, Xavier init, the safetensors round
//! trip, the shipped file, and one crafted file per rejection rule of §8.5.

use std::path::{Path, PathBuf};

use densefeat::nn::weights::{fans, tensor_specs, MAX_HEADER_BYTES};
use densefeat::nn::NetworkWeights;
use densefeat::ops::NetworkConfig;
use densefeat::Error;
use serde_json::{json, Value};

fn small_config() -> NetworkConfig {
    NetworkConfig { blocks: 2, channels: 2, b1_stride: 2, input_mean: [1.5, 2.0, 3.25] }
}

fn small_weights() -> NetworkWeights {
    NetworkWeights::xavier_uniform(&small_config(), 3).expect("init")
}

/// A file from its parts: 8-byte LE header length, header, data.
fn craft(header: &[u8], data: &[u8]) -> Vec<u8> {
    let mut bytes = (header.len() as u64).to_le_bytes().to_vec();
    bytes.extend_from_slice(header);
    bytes.extend_from_slice(data);
    bytes
}

/// The valid file of [`small_weights`], split into its header JSON and data.
fn valid_parts() -> (Value, Vec<u8>) {
    let bytes = small_weights().to_safetensors_bytes().expect("bytes");
    let n = u64::from_le_bytes(bytes[..8].try_into().unwrap()) as usize;
    let header: Value = serde_json::from_slice(&bytes[8..8 + n]).expect("json");
    (header, bytes[8 + n..].to_vec())
}

fn craft_json(header: &Value, data: &[u8]) -> Vec<u8> {
    craft(header.to_string().as_bytes(), data)
}

/// Loads `bytes` from a file and returns the error message, checking it is a `BadFile` naming the file.
#[track_caller]
fn rejection(bytes: &[u8]) -> String {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("crafted.safetensors");
    std::fs::write(&path, bytes).unwrap();
    match NetworkWeights::load(&path) {
        Ok(_) => panic!("crafted file was accepted"),
        Err(e @ Error::BadFile { .. }) => {
            let Error::BadFile { path: p, what } = &e else { unreachable!() };
            assert_eq!(p, &path, "error must name the file");
            assert!(e.to_string().contains("crafted.safetensors"), "{e}");
            what.clone()
        }
        Err(other) => panic!("expected BadFile, got {other:?}"),
    }
}

#[track_caller]
fn assert_rejected(bytes: &[u8], needle: &str) {
    let what = rejection(bytes);
    assert!(what.contains(needle), "message {what:?} should contain {needle:?}");
}

#[test]
fn tensor_names_are_pytorch_state_dict_keys() {
    // FeatureNet(blocks=2).state_dict().keys() and shapes for channels 2.
    let want = [
        ("blocks.0.conv1.weight", vec![2, 3, 3, 3]),
        ("blocks.0.conv1.bias", vec![2]),
        ("blocks.0.conv2.weight", vec![2, 2, 3, 3]),
        ("blocks.0.conv2.bias", vec![2]),
        ("blocks.0.conv3.weight", vec![2, 2, 3, 3]),
        ("blocks.0.conv3.bias", vec![2]),
        ("blocks.1.conv1.weight", vec![2, 5, 3, 3]),
        ("blocks.1.conv1.bias", vec![2]),
        ("blocks.1.conv2.weight", vec![2, 2, 3, 3]),
        ("blocks.1.conv2.bias", vec![2]),
        ("blocks.1.conv3.weight", vec![2, 2, 3, 3]),
        ("blocks.1.conv3.bias", vec![2]),
        ("deconvs.0.weight", vec![2, 2, 5, 5]),
        ("deconvs.0.bias", vec![2]),
    ];
    let got: Vec<(String, Vec<usize>)> =
        tensor_specs(&small_config()).into_iter().map(|s| (s.name, s.shape)).collect();
    let want: Vec<(String, Vec<usize>)> = want.into_iter().map(|(n, s)| (n.to_string(), s)).collect();
    assert_eq!(got, want);
    let one_block = NetworkConfig { blocks: 1, ..small_config() };
    assert_eq!(tensor_specs(&one_block).len(), 6, "no deconvs for one block");
}

#[test]
fn xavier_uniform_follows_pytorch_fans_and_zero_biases() {
    // PyTorch: fan_in = size(1)·k·k, fan_out = size(0)·k·k.
    assert_eq!(fans(&[32, 35, 3, 3]), (315, 288));
    assert_eq!(fans(&[32, 16, 5, 5]), (400, 800), "ConvTranspose2d [in, out, k, k]: fan_in from dim 1");
    let config = NetworkConfig::default();
    let w = NetworkWeights::xavier_uniform(&config, 0).unwrap();
    for (layer, spec) in w.layers().iter().zip(tensor_specs(&config).chunks_exact(2)) {
        let shape: [usize; 4] = spec[0].shape.clone().try_into().unwrap();
        let (fan_in, fan_out) = fans(&shape);
        let a = (6.0 / (fan_in + fan_out) as f64).sqrt() as f32;
        let max = layer.weight.iter().fold(0.0f32, |m, v| m.max(v.abs()));
        assert!(max <= a && max > 0.9 * a, "{}: max {max}, bound {a}", spec[0].name);
        let mean = layer.weight.iter().map(|&v| f64::from(v)).sum::<f64>() / layer.weight.len() as f64;
        assert!(mean.abs() < 0.1 * f64::from(a), "{}: mean {mean}", spec[0].name);
        assert!(layer.bias.iter().all(|&b| b == 0.0));
    }
    assert_eq!(w, NetworkWeights::xavier_uniform(&config, 0).unwrap(), "same seed, same weights");
    assert_ne!(w.blocks[0], NetworkWeights::xavier_uniform(&config, 1).unwrap().blocks[0]);
}

#[test]
fn save_load_round_trip_is_exact_and_reproducible() {
    let dir = tempfile::tempdir().unwrap();
    let path = dir.path().join("w.safetensors");
    let mut w = small_weights();
    w.blocks[1].conv2.bias[1] = -0.0;
    w.deconvs[0].bias[0] = f32::MIN_POSITIVE / 4.0; // subnormal
    w.save(&path).unwrap();
    let back = NetworkWeights::load(&path).unwrap();
    assert_eq!(back, w);
    assert_eq!(back.deconvs[0].bias[0].to_bits(), w.deconvs[0].bias[0].to_bits());
    assert_eq!(std::fs::read(&path).unwrap(), w.to_safetensors_bytes().unwrap(), "byte-reproducible");
    let leftovers: Vec<_> = std::fs::read_dir(dir.path()).unwrap().collect();
    assert_eq!(leftovers.len(), 1, "atomic save leaves no temporary file");
}

#[test]
fn shipped_init_weights_load_and_match_their_recipe() {
    let path =
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fixtures/weights/featurenet_init_seed0.safetensors");
    let w = NetworkWeights::load(&path).unwrap();
    assert_eq!((w.config.blocks, w.config.channels, w.config.b1_stride), (5, 32, 2));
    assert_eq!(w.provenance, "xavier-uniform seed=0");
    let recipe = NetworkWeights::xavier_uniform(&w.config, 0).unwrap();
    assert_eq!(w, recipe);
    assert!(w.config.input_mean.iter().all(|m| (50.0..150.0).contains(m)), "{:?}", w.config.input_mean);
}

// ---------------------------------------------------------------------------------------------
// Rejections (SPEC.md §8.5), one crafted file each.

#[test]
fn rejects_truncated_files() {
    assert_rejected(&[1, 0, 0], "truncated");
    let (header, data) = valid_parts();
    let full = craft_json(&header, &data);
    assert_rejected(&full[..20], "truncated");
}

#[test]
fn rejects_header_over_the_cap() {
    let mut bytes = ((MAX_HEADER_BYTES + 1) as u64).to_le_bytes().to_vec();
    bytes.extend_from_slice(b"{}");
    assert_rejected(&bytes, "cap");
}

#[test]
fn rejects_header_that_is_not_json() {
    assert_rejected(&craft(b"{\"__metadata__\": nope", &[]), "not JSON");
    assert_rejected(&craft(&[0xff, 0xfe, b'{', b'}'], &[]), "not JSON");
}

#[test]
fn rejects_missing_metadata() {
    let (mut header, data) = valid_parts();
    header.as_object_mut().unwrap().remove("__metadata__");
    assert_rejected(&craft_json(&header, &data), "no __metadata__");
    let (mut header, data) = valid_parts();
    header["__metadata__"].as_object_mut().unwrap().remove("provenance");
    assert_rejected(&craft_json(&header, &data), "missing key \"provenance\"");
}

#[test]
fn rejects_malformed_metadata() {
    let cases = [
        ("format", json!("densefeat-featurenet-v0"), "format"),
        ("blocks", json!("six"), "blocks"),
        ("blocks", json!("6"), "blocks"),
        ("blocks", json!(2), "not a string"),
        ("b1_stride", json!("3"), "b1_stride"),
        ("channels", json!("0"), "channels"),
        ("input_mean", json!("1,2"), "input_mean"),
        ("input_mean", json!("1,2,nan"), "input_mean"),
    ];
    for (key, value, needle) in cases {
        let (mut header, data) = valid_parts();
        header["__metadata__"][key] = value;
        assert_rejected(&craft_json(&header, &data), needle);
    }
}

#[test]
fn rejects_missing_tensor() {
    let (mut header, data) = valid_parts();
    header.as_object_mut().unwrap().remove("deconvs.0.bias");
    assert_rejected(&craft_json(&header, &data), "missing [\"deconvs.0.bias\"]");
}

#[test]
fn rejects_extra_tensor() {
    let (mut header, mut data) = valid_parts();
    let end = data.len();
    header["blocks.2.conv1.bias"] = json!({"dtype": "F32", "shape": [1], "data_offsets": [end, end + 4]});
    data.extend_from_slice(&0f32.to_le_bytes());
    assert_rejected(&craft_json(&header, &data), "unexpected [\"blocks.2.conv1.bias\"]");
}

#[test]
fn rejects_wrong_shape() {
    let (mut header, data) = valid_parts();
    header["blocks.0.conv1.weight"]["shape"] = json!([2, 3, 9]); // same element count
    assert_rejected(&craft_json(&header, &data), "blocks.0.conv1.weight: shape [2, 3, 9]");
}

#[test]
fn rejects_wrong_dtype() {
    let (mut header, data) = valid_parts();
    header["blocks.0.conv1.bias"]["dtype"] = json!("I32");
    assert_rejected(&craft_json(&header, &data), "dtype I32, expected F32");
}

#[test]
fn rejects_data_size_mismatch() {
    let (header, mut data) = valid_parts();
    data.extend_from_slice(&[0; 4]);
    assert_rejected(&craft_json(&header, &data), "data size mismatch");
    let (header, data) = valid_parts();
    assert_rejected(&craft_json(&header, &data[..data.len() - 4]), "data size mismatch");
    let (mut header, data) = valid_parts();
    header["deconvs.0.bias"]["data_offsets"][1] =
        json!(header["deconvs.0.bias"]["data_offsets"][1].as_u64().unwrap() - 4);
    assert_rejected(&craft_json(&header, &data), "data size mismatch");
}

#[test]
fn rejects_non_finite_values() {
    for bad in [f32::NAN, f32::INFINITY, f32::NEG_INFINITY] {
        let (header, mut data) = valid_parts();
        let at = header["blocks.1.conv2.weight"]["data_offsets"][0].as_u64().unwrap() as usize + 8;
        data[at..at + 4].copy_from_slice(&bad.to_le_bytes());
        assert_rejected(&craft_json(&header, &data), "blocks.1.conv2.weight: non-finite value");
    }
}

#[test]
fn missing_file_is_an_io_error_naming_it() {
    let path = Path::new("/nonexistent/w.safetensors");
    match NetworkWeights::load(path) {
        Err(Error::Io { path: p, .. }) => assert_eq!(p, path),
        other => panic!("expected Io error, got {other:?}"),
    }
}

/// The shipped weights `fixtures/weights/NAME`, checked to be the end of their training chain
/// (docs/training/README.md): 5 blocks of 32 channels at block-1 stride `b1_stride`, provenance
/// "step `steps` of `steps`", and trained (not the initialisation). Returns the file's bytes.
fn shipped_chain_end(name: &str, b1_stride: usize, steps: usize) -> Vec<u8> {
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("fixtures/weights").join(name);
    let w = NetworkWeights::load(&path).unwrap();
    assert_eq!((w.config.blocks, w.config.channels, w.config.b1_stride), (5, 32, b1_stride));
    let want = format!("densefeat train: step {steps} of {steps}");
    assert!(w.provenance.starts_with(&want), "{}", w.provenance);
    let init = densefeat::train::trainer::training_init(&w.config, 0).unwrap();
    assert_ne!(w, init);
    std::fs::read(&path).unwrap()
}

#[test]
fn shipped_trained_weights_load_and_are_the_built_in_default() {
    // Chain mf8sow: chain mf8so's end trained 5 000 more steps with the five block scales' losses
    // weighted 0.2 against L's 1 (--deep-weight 0.2; 8 live frames, the mask and same-window crops
    // kept, data seed 12; SPEC.md §13.8).
    let bytes = shipped_chain_end("featurenet_trained_mf8sow.safetensors", 2, 5000);
    assert_eq!(bytes, densefeat::mapping::features::SHIPPED_WEIGHTS);
    let w = NetworkWeights::from_safetensors_bytes(&bytes, Path::new("mf8sow")).unwrap();
    assert!(
        w.provenance.contains("live_frames: 8, live_crop: Same, occlusion_tolerance: 0.05"),
        "{}",
        w.provenance
    );
    assert!(w.provenance.contains("seed=12 "), "{}", w.provenance);
    assert!(w
        .provenance
        .contains("supervision=Supervision { deep: true, aggregated: true, deep_weight: 0.2 }"));
    assert!(w.provenance.contains("init_weights=docs/training/chain_mf8so/weights.safetensors"));
}

#[test]
fn shipped_eight_frame_weights_load_and_are_the_end_of_their_chain() {
    // Chain mf8so: chain mf4so's end trained 5 000 more steps with 8 live frames per reference
    // (the mask and same-window crops kept, data seed 10); the default on 2026-12-07 until mf8sow
    // and mf8sow's start (its weights are the bytes of docs/training/chain_mf8so/weights.safetensors).
    let bytes = shipped_chain_end("featurenet_trained_mf8so.safetensors", 2, 5000);
    assert_ne!(bytes, densefeat::mapping::features::SHIPPED_WEIGHTS);
    let start = std::fs::read(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("docs/training/chain_mf8so/weights.safetensors"),
    )
    .unwrap();
    assert_eq!(bytes, start);
    let w = NetworkWeights::from_safetensors_bytes(&bytes, Path::new("mf8so")).unwrap();
    assert!(
        w.provenance.contains("live_frames: 8, live_crop: Same, occlusion_tolerance: 0.05"),
        "{}",
        w.provenance
    );
    assert!(w.provenance.contains("seed=10 "), "{}", w.provenance);
    assert!(w.provenance.contains("init_weights=docs/training/chain_mf4so/weights.safetensors"));
}

#[test]
fn shipped_masked_four_frame_weights_load_and_are_the_end_of_their_chain() {
    // Chain mf4so: chain mf4sc's 5 000 steps x 4 tuples (the multi-frame loss, same-window live
    // crops, from chain mf4l's end, the same data draws) with occlusion masking (SPEC.md §13.1c);
    // the default on 2026-12-06 and mf8so's start (its weights are the bytes of
    // docs/training/chain_mf4so/weights.safetensors).
    let bytes = shipped_chain_end("featurenet_trained_mf4so.safetensors", 2, 5000);
    assert_ne!(bytes, densefeat::mapping::features::SHIPPED_WEIGHTS);
    let start = std::fs::read(
        PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("docs/training/chain_mf4so/weights.safetensors"),
    )
    .unwrap();
    assert_eq!(bytes, start);
    let w = NetworkWeights::from_safetensors_bytes(&bytes, Path::new("mf4so")).unwrap();
    assert!(
        w.provenance.contains("live_frames: 4, live_crop: Same, occlusion_tolerance: 0.05"),
        "{}",
        w.provenance
    );
    assert!(w.provenance.contains("seed=4 "), "{}", w.provenance);
    assert!(w.provenance.contains("init_weights=docs/training/chain_mf4l/best_weights.safetensors"));
}

#[test]
fn shipped_unmasked_weights_load_and_are_the_end_of_their_chain() {
    // Chain mf4sc: mf4so's fine-tune without occlusion masking; the default from 2026-12-05 to
    // 2026-12-06 and mf4so's control.
    let bytes = shipped_chain_end("featurenet_trained_mf4sc.safetensors", 2, 5000);
    assert_ne!(bytes, densefeat::mapping::features::SHIPPED_WEIGHTS);
    let w = NetworkWeights::from_safetensors_bytes(&bytes, Path::new("mf4sc")).unwrap();
    assert!(w.provenance.contains("live_frames: 4, live_crop: Same }"), "{}", w.provenance);
    assert!(w.provenance.contains("init_weights=docs/training/chain_mf4l/best_weights.safetensors"));
}

#[test]
fn shipped_flow_crop_weights_load_and_are_the_end_of_their_chain() {
    // Chain mf4l: 10 000 steps x 4 tuples of the multi-frame loss (flow-shifted live crops),
    // fine-tuning chain b1s2's end; the default from 2026-12-04 to 2026-12-05 and mf4sc's start.
    let bytes = shipped_chain_end("featurenet_trained_mf4l.safetensors", 2, 10000);
    assert_ne!(bytes, densefeat::mapping::features::SHIPPED_WEIGHTS);
    let w = NetworkWeights::from_safetensors_bytes(&bytes, Path::new("mf4l")).unwrap();
    assert!(w.provenance.contains("live_frames: 4"), "{}", w.provenance);
    assert!(!w.provenance.contains("live_crop"), "{}", w.provenance);
    assert!(w.provenance.contains("init_weights=fixtures/weights/featurenet_trained_b1s2.safetensors"));
}

#[test]
fn shipped_pair_loss_weights_load_and_are_the_end_of_their_chain() {
    // Chain b1s2: 37 500 steps x 4 pairs; the default until 2026-12-04 and mf4l's starting point.
    let bytes = shipped_chain_end("featurenet_trained_b1s2.safetensors", 2, 37500);
    assert_ne!(bytes, densefeat::mapping::features::SHIPPED_WEIGHTS);
}

#[test]
fn shipped_stride_1_weights_load_and_are_the_end_of_their_chain() {
    // Chain b1s1: 15 000 steps x 4 pairs; not the built-in default.
    let bytes = shipped_chain_end("featurenet_trained_b1s1.safetensors", 1, 15000);
    assert_ne!(bytes, densefeat::mapping::features::SHIPPED_WEIGHTS);
}
