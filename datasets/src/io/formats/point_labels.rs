//! Point labels of photographs: one `NAME.csv` per photo `NAME.jpg`, a
//! header starting `x,y`, then rows whose first two fields are a point in
//! MATLAB's pixel convention (pixel centres at integers from 1) and whose
//! optional third field names its kind, as York Urban's
//! `junctions_derived/*.csv` (`x,y,type,seg_i,seg_j`, type `L` or `T`).

use std::path::{Path, PathBuf};

use crate::bbox::BBox;
use crate::error::{DataError, Result};
use crate::io::formats::{CocoAnnotation, CocoDataset, CocoImage, corner_categories};

/// One labelled point, in box coordinates (pixel (i, j) spans
/// [i, i + 1) x [j, j + 1)).
#[derive(Debug, Clone, PartialEq)]
pub struct PointLabel {
    pub point: [f32; 2],
    /// The third field of the row (York Urban: `L` or `T`), if any.
    pub kind: Option<String>,
}

/// Reads a point-label CSV; a bad row is an error naming the file and line.
pub fn read_point_labels(path: &Path) -> Result<Vec<PointLabel>> {
    let text = crate::atomic::read_text(path)?;
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, header)) if header.trim_start().starts_with("x,y") => {}
        _ => return Err(DataError::invalid(path, "no `x,y,...` header on the first line")),
    }
    let mut labels = Vec::new();
    for (k, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let mut fields = line.split(',');
        let mut number = |name: &str| -> Result<f32> {
            let field = fields.next().unwrap_or("").trim();
            field.parse::<f32>().ok().filter(|v| v.is_finite()).ok_or_else(|| {
                DataError::invalid(path, format!("line {}: {name} `{field}` is not a finite number", k + 1))
            })
        };
        let (x, y) = (number("x")?, number("y")?);
        let kind = fields.next().map(str::trim).filter(|t| !t.is_empty()).map(str::to_string);
        // MATLAB's pixel 1 has its centre at 1; in box coordinates at 0.5.
        labels.push(PointLabel { point: [x - 0.5, y - 0.5], kind });
    }
    Ok(labels)
}

/// Writes points given in box coordinates as a point-label CSV (`x,y`,
/// MATLAB's pixel convention), the file `read_point_labels` reads back.
pub fn write_point_labels(path: &Path, points: &[[f64; 2]]) -> Result<()> {
    let mut text = String::from("x,y\n");
    for p in points {
        text.push_str(&format!("{},{}\n", p[0] + 0.5, p[1] + 0.5));
    }
    crate::atomic::write_bytes(path, text.as_bytes())
}

/// The photographs (.jpg, .jpeg, .png) of `images` that have a `NAME.csv` in
/// `points`, each with that file, sorted by path. None is an error.
pub fn labelled_photos(images: &Path, points: &Path) -> Result<Vec<(PathBuf, PathBuf)>> {
    let entries = std::fs::read_dir(images).map_err(|e| DataError::io(images, e))?;
    let mut found = Vec::new();
    for entry in entries {
        let path = entry.map_err(|e| DataError::io(images, e))?.path();
        let extension = path.extension().and_then(|e| e.to_str()).map(|e| e.to_ascii_lowercase());
        if !matches!(extension.as_deref(), Some("jpg" | "jpeg" | "png")) {
            continue;
        }
        let Some(stem) = path.file_stem().and_then(|s| s.to_str()) else { continue };
        let labels = points.join(format!("{stem}.csv"));
        if labels.is_file() {
            found.push((path, labels));
        }
    }
    found.sort();
    if found.is_empty() {
        let message = format!("no photograph in this folder has a NAME.csv in {}", points.display());
        return Err(DataError::invalid(images, message));
    }
    Ok(found)
}

/// A training and a test half of labelled photos, as COCO sets.
#[derive(Debug, Clone)]
pub struct CocoHalves {
    /// Training, then test.
    pub halves: [CocoDataset; 2],
    /// Labelled points outside their photo, left out.
    pub outside: usize,
}

/// Splits `photos` (photo, label file; as `labelled_photos` lists them)
/// into a training and a test half, every `test_every`-th photo to the test
/// half (1 or 0: every photo), with a `box_size` square box around every
/// point, clipped to the photo. Photos are named by absolute path: they need not be copied.
pub fn coco_halves(photos: &[(PathBuf, PathBuf)], test_every: usize, box_size: f32) -> Result<CocoHalves> {
    let mut halves = [CocoDataset::default(), CocoDataset::default()];
    for half in &mut halves {
        half.categories = corner_categories();
    }
    let (mut next_annotation, mut outside) = (0u64, 0usize);
    for (index, (photo, labels_path)) in photos.iter().enumerate() {
        let (width, height) = image::image_dimensions(photo).map_err(|e| DataError::image(photo, e))?;
        let absolute = std::fs::canonicalize(photo).map_err(|e| DataError::io(photo, e))?;
        let Some(file_name) = absolute.to_str() else {
            return Err(DataError::invalid(&absolute, "the path is not UTF-8"));
        };
        let half = &mut halves[usize::from((index + 1) % test_every.max(1) == 0)];
        let image_id = index as u64 + 1;
        half.images.push(CocoImage { id: image_id, file_name: file_name.to_string(), width, height });
        for label in read_point_labels(labels_path)? {
            let [x, y] = label.point;
            if !(x >= 0.0 && y >= 0.0 && x < width as f32 && y < height as f32) {
                outside += 1;
                continue;
            }
            let bbox = BBox::around(x, y, box_size).clip(width as f32, height as f32);
            next_annotation += 1;
            half.annotations.push(CocoAnnotation {
                id: next_annotation,
                image_id,
                category_id: 1,
                bbox: bbox.to_xywh(),
                area: bbox.area(),
                iscrowd: 0,
                corner_type: label.kind,
                point: Some(label.point),
            });
        }
    }
    Ok(CocoHalves { halves, outside })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn matlab_points_move_to_box_coordinates_and_bad_rows_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let good = dir.path().join("good.csv");
        std::fs::write(&good, "x,y,type,seg_i,seg_j\n1,1,L,1,2\n248.44,279.72,T,1,14\n\n").unwrap();
        let labels = read_point_labels(&good).unwrap();
        assert_eq!(labels.iter().map(|l| l.point).collect::<Vec<_>>(), vec![[0.5, 0.5], [247.94, 279.22]]);
        assert_eq!(labels.iter().map(|l| l.kind.as_deref()).collect::<Vec<_>>(), [Some("L"), Some("T")]);
        let plain = dir.path().join("plain.csv");
        std::fs::write(&plain, "x,y\n3,4\n").unwrap();
        assert_eq!(read_point_labels(&plain).unwrap(), [PointLabel { point: [2.5, 3.5], kind: None }]);
        let bad = dir.path().join("bad.csv");
        std::fs::write(&bad, "x,y,type\n1,2,L\n3,nan,T\n").unwrap();
        let message = read_point_labels(&bad).unwrap_err().to_string();
        assert!(message.contains("bad.csv") && message.contains("line 3") && message.contains("y `nan`"), "{message}");
        let written = dir.path().join("written.csv");
        write_point_labels(&written, &[[247.94, 279.22], [0.0, 12.25]]).unwrap();
        let back: Vec<[f32; 2]> = read_point_labels(&written).unwrap().into_iter().map(|l| l.point).collect();
        assert_eq!(back, [[247.94, 279.22], [0.0, 12.25]]);
        let headless = dir.path().join("headless.csv");
        std::fs::write(&headless, "1,2\n").unwrap();
        assert!(read_point_labels(&headless).unwrap_err().to_string().contains("header"));
    }

    #[test]
    fn photos_pair_with_their_label_files() {
        let dir = tempfile::tempdir().unwrap();
        let (images, points) = (dir.path().join("images"), dir.path().join("points"));
        std::fs::create_dir_all(&images).unwrap();
        std::fs::create_dir_all(&points).unwrap();
        for name in ["b.jpg", "a.PNG", "c.jpg", "notes.txt"] {
            std::fs::write(images.join(name), b"").unwrap();
        }
        for name in ["a.csv", "b.csv", "notes.csv"] {
            std::fs::write(points.join(name), "x,y\n").unwrap();
        }
        let found = labelled_photos(&images, &points).unwrap();
        let names: Vec<_> = found.iter().map(|(p, l)| (p.file_name().unwrap(), l.file_name().unwrap())).collect();
        assert_eq!(names, [("a.PNG".as_ref(), "a.csv".as_ref()), ("b.jpg".as_ref(), "b.csv".as_ref())]);
        let error = labelled_photos(&points, &images).unwrap_err().to_string();
        assert!(error.contains("no photograph") && error.contains("points"), "{error}");
        assert!(labelled_photos(&dir.path().join("missing"), &points).is_err());
    }

    #[test]
    fn york_urban_junctions_read_where_the_shared_data_is() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/data/york_urban_lines/junctions_derived/P1020171.csv");
        if !path.is_file() {
            eprintln!("skipped: {} is not here", path.display());
            return;
        }
        let labels = read_point_labels(&path).unwrap();
        assert!(labels.len() > 10, "{} junctions", labels.len());
        let first = labels[0].point;
        assert!((first[0] - 247.94).abs() < 1e-4 && (first[1] - 279.22).abs() < 1e-4, "{first:?}");
        assert!(labels.iter().all(|l| (0.0..640.0).contains(&l.point[0]) && (0.0..480.0).contains(&l.point[1])));
        assert!(labels.iter().all(|l| matches!(l.kind.as_deref(), Some("L" | "T"))));
    }
}
