//! The crate's three layers depend one way: the shared root on neither
//! `io` nor `simulator`, `io` not on `simulator`. Checked on the source, so a
//! new `use` that turns an arrow around fails here rather than in review.

use std::path::{Path, PathBuf};

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("source folder") {
        let path = entry.expect("entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// The layers a file's code names through `crate::`, comments left out.
fn layers_named(source: &str) -> Vec<&'static str> {
    let code: String = source.lines().map(|line| line.split("//").next().unwrap_or("")).collect::<Vec<_>>().join("\n");
    let mut named = Vec::new();
    for (at, _) in code.match_indices("crate::") {
        let rest = &code[at + "crate::".len()..];
        // `crate::{io, math}` names every module of the group.
        let names =
            if let Some(group) = rest.strip_prefix('{') { &group[..group.find('}').unwrap_or(0)] } else { rest };
        for layer in ["io", "simulator"] {
            let hit = names
                .split(|c: char| !(c.is_alphanumeric() || c == '_'))
                .take(if rest.starts_with('{') { usize::MAX } else { 1 })
                .any(|word| word == layer);
            if hit && !named.contains(&layer) {
                named.push(layer);
            }
        }
    }
    named
}

#[test]
fn the_layers_of_datasets_depend_one_way() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src, &mut files);
    let mut wrong = Vec::new();
    for file in &files {
        let relative = file.strip_prefix(&src).expect("under src");
        let top = relative.components().next().expect("a component").as_os_str().to_string_lossy().into_owned();
        let forbidden: &[&str] = match top.as_str() {
            // The crate root declares the layers; the binaries and the simulator stand above them.
            "lib.rs" | "bin" | "simulator" => continue,
            "io" => &["simulator"],
            _ => &["io", "simulator"],
        };
        let source = std::fs::read_to_string(file).expect("readable source");
        for layer in layers_named(&source) {
            if forbidden.contains(&layer) {
                wrong.push(format!("{} uses crate::{layer}", relative.display()));
            }
        }
    }
    assert!(files.len() > 50, "found only {} source files under {}", files.len(), src.display());
    assert!(wrong.is_empty(), "imports against the layering:\n{}", wrong.join("\n"));
}

#[test]
fn the_layer_check_sees_plain_and_grouped_imports() {
    assert_eq!(layers_named("use crate::io::formats::Pcd;"), vec!["io"]);
    assert_eq!(layers_named("use crate::{math, simulator::world};"), vec!["simulator"]);
    assert_eq!(layers_named("let x = crate::simulator::generate::key(1, 2, 3);"), vec!["simulator"]);
    assert!(layers_named("use crate::math::iou; // not crate::io").is_empty());
    assert!(layers_named("use crate::image_size::ImageSize;").is_empty());
}
