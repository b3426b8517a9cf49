//! Box IoU, box coding, anchors, NMS, clipping, small-box removal and
//! RoIAlign against torchvision's own numbers. The fixture and the script
//! that wrote it (`fixtures/make_reference.py`, torchvision 0.29) sit beside
//! this file. Tolerances: 1e-5 relative for box arithmetic (f32), exact for
//! indices, 1e-5 absolute for RoIAlign.

use burn::prelude::*;
use infer::anchors::AnchorConfig;
use infer::boxes::{BBox, BoxCoder, batched_nms, box_iou, nms, remove_small};
use infer::roi_align::{roi_align, roi_align_grid_sample};
use serde_json::Value;

/// The package folder, read when the test runs (cargo sets it), so that a
/// test binary reused from another checkout still finds its files.
fn manifest_dir() -> std::path::PathBuf {
    std::env::var_os("CARGO_MANIFEST_DIR").map_or_else(|| env!("CARGO_MANIFEST_DIR").into(), Into::into)
}

fn fixture() -> Value {
    let text = std::fs::read_to_string(manifest_dir().join("tests/fixtures/torchvision_reference.json")).unwrap();
    serde_json::from_str(&text).unwrap()
}

fn boxes(v: &Value) -> Vec<BBox> {
    v.as_array()
        .unwrap()
        .iter()
        .map(|r| {
            let r: Vec<f32> = r.as_array().unwrap().iter().map(|x| x.as_f64().unwrap() as f32).collect();
            BBox::new(r[0], r[1], r[2], r[3])
        })
        .collect()
}

fn floats(v: &Value) -> Vec<f32> {
    v.as_array().unwrap().iter().map(|x| x.as_f64().unwrap() as f32).collect()
}

fn indices(v: &Value) -> Vec<usize> {
    v.as_array().unwrap().iter().map(|x| x.as_u64().unwrap() as usize).collect()
}

fn close(a: f32, b: f32, what: &str) {
    let tol = 1e-5 * (1.0 + b.abs());
    assert!((a - b).abs() <= tol, "{what}: ours {a}, torchvision {b}");
}

fn close_box(a: &BBox, b: &BBox, what: &str) {
    for (x, y) in [(a.x1, b.x1), (a.y1, b.y1), (a.x2, b.x2), (a.y2, b.y2)] {
        close(x, y, what);
    }
}

#[test]
fn box_iou_matches() {
    let f = fixture();
    let (a, b) = (boxes(&f["iou"]["a"]), boxes(&f["iou"]["b"]));
    let ours = box_iou(&a, &b);
    for (i, row) in f["iou"]["iou"].as_array().unwrap().iter().enumerate() {
        for (j, v) in floats(row).iter().enumerate() {
            close(ours[i][j], *v, &format!("iou[{i}][{j}]"));
        }
    }
}

#[test]
fn box_coding_matches_including_the_size_clamp() {
    let f = fixture();
    let c = &f["coding"];
    let (reference, target) = (boxes(&c["reference"]), boxes(&c["target"]));
    for name in ["unit", "head"] {
        let w = floats(&c[name]["weights"]);
        let coder = BoxCoder::new([w[0], w[1], w[2], w[3]]);
        let deltas: Vec<Vec<f32>> = c[name]["deltas"].as_array().unwrap().iter().map(floats).collect();
        for (k, d) in deltas.iter().enumerate() {
            let ours = coder.encode(&reference[k], &target[k]);
            for j in 0..4 {
                close(ours[j], d[j], &format!("{name} encode {k}.{j}"));
            }
        }
        for key in ["deltas", "wild_deltas"] {
            let decoded_key = if key == "deltas" { "decoded" } else { "wild_decoded" };
            let want = boxes(&c[name][decoded_key]);
            for (k, d) in c[name][key].as_array().unwrap().iter().map(floats).enumerate() {
                close_box(
                    &coder.decode(&reference[k], [d[0], d[1], d[2], d[3]]),
                    &want[k],
                    &format!("{name} {decoded_key} {k}"),
                );
            }
        }
    }
}

#[test]
fn anchors_match_in_value_and_order() {
    let f = fixture();
    let a = &f["anchors"];
    let config = AnchorConfig { sizes: floats(&a["sizes"]), aspect_ratios: floats(&a["aspect_ratios"]) };
    let ours =
        config.grid_anchors(a["grid_h"].as_u64().unwrap() as usize, a["grid_w"].as_u64().unwrap() as usize, 16.0);
    let want = boxes(&a["anchors"]);
    assert_eq!(ours.len(), want.len());
    for (k, (o, w)) in ours.iter().zip(&want).enumerate() {
        close_box(o, w, &format!("anchor {k}"));
    }
}

#[test]
fn nms_and_batched_nms_keep_the_same_boxes_in_the_same_order() {
    let f = fixture();
    let n = &f["nms"];
    let (b, s) = (boxes(&n["boxes"]), floats(&n["scores"]));
    let classes = indices(&n["classes"]);
    assert_eq!(nms(&b, &s, 0.5), indices(&n["keep_05"]));
    assert_eq!(nms(&b, &s, 0.7), indices(&n["keep_07"]));
    assert_eq!(batched_nms(&b, &s, &classes, 0.5), indices(&n["batched_keep_05"]));
}

#[test]
fn clipping_and_small_box_removal_match() {
    let f = fixture();
    let c = &f["clip"];
    let (w, h) = (c["width"].as_f64().unwrap() as f32, c["height"].as_f64().unwrap() as f32);
    for (k, (b, want)) in boxes(&c["boxes"]).iter().zip(boxes(&c["clipped"])).enumerate() {
        close_box(&b.clip(w, h), &want, &format!("clip {k}"));
    }
    let s = &f["small"];
    assert_eq!(remove_small(&boxes(&s["boxes"]), s["min_size"].as_f64().unwrap() as f32), indices(&s["keep"]));
}

#[test]
fn roi_align_matches_for_boxes_inside_the_map() {
    roi_align_matches_on(Device::flex(), roi_align);
}

/// Under autodiff (the training path) the native kernel runs too.
#[test]
fn roi_align_matches_under_autodiff() {
    roi_align_matches_on(Device::flex().autodiff(), roi_align);
}

/// The `grid_sample_2d` composition, which other devices use.
#[test]
fn roi_align_composition_matches_for_boxes_inside_the_map() {
    roi_align_matches_on(Device::flex(), roi_align_grid_sample);
    roi_align_matches_on(Device::flex().autodiff(), roi_align_grid_sample);
}

type RoiAlignFn = fn(Tensor<4>, &[BBox], usize, usize) -> Tensor<4>;

fn roi_align_matches_on(device: Device, op: RoiAlignFn) {
    let f = fixture();
    let r = &f["roi_align"];
    let shape: Vec<usize> = indices(&r["shape"]);
    let map =
        Tensor::<4>::from_data(TensorData::new(floats(&r["features"]), [1, shape[0], shape[1], shape[2]]), &device);
    let rois = boxes(&r["rois"]);
    let out = infer::host(op(
        map,
        &rois,
        r["output_size"].as_u64().unwrap() as usize,
        r["sampling_ratio"].as_u64().unwrap() as usize,
    ));
    let want = floats(&r["output"]);
    assert_eq!(out.len(), want.len());
    let worst = out.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
    assert!(worst < 1e-5, "largest difference {worst}");
}

/// Boxes across the border (clamped and zeroed samples) and the gradient
/// with respect to the feature map, against torchvision's autograd.
#[test]
fn native_roi_align_matches_at_the_border_and_in_its_gradient() {
    roi_align_matches_at_the_border(roi_align);
}

/// The composition too: a GPU's detections on boxes at the image edge are the CPU's.
#[test]
fn roi_align_composition_matches_at_the_border_and_in_its_gradient() {
    roi_align_matches_at_the_border(roi_align_grid_sample);
}

fn roi_align_matches_at_the_border(op: RoiAlignFn) {
    let f = fixture();
    let r = &f["roi_align_border"];
    let shape: Vec<usize> = indices(&r["shape"]);
    let device = Device::flex().autodiff();
    let dims = [1, shape[0], shape[1], shape[2]];
    let map = Tensor::<4>::from_data(TensorData::new(floats(&r["features"]), dims), &device).require_grad();
    let rois = boxes(&r["rois"]);
    let (output, sampling) =
        (r["output_size"].as_u64().unwrap() as usize, r["sampling_ratio"].as_u64().unwrap() as usize);
    let pooled = op(map.clone(), &rois, output, sampling);
    let weights = Tensor::<4>::from_data(TensorData::new(floats(&r["weights"]), pooled.dims()), &device);
    let grads = (pooled.clone() * weights).sum().backward();
    for (what, ours, want) in [
        ("output", infer::host(pooled), floats(&r["output"])),
        ("gradient", infer::host(map.grad(&grads).unwrap()), floats(&r["features_grad"])),
    ] {
        assert_eq!(ours.len(), want.len(), "{what}");
        let worst = ours.iter().zip(&want).map(|(a, b)| (a - b).abs()).fold(0.0f32, f32::max);
        assert!(worst < 1e-5, "{what}: largest difference {worst}");
    }
}
