//! Detections scored against point labels on photographs (York Urban's
//! junctions, or any folder of `NAME.csv` files beside `NAME.jpg`): what
//! share of the points a method gives lie within a radius of a labelled
//! point (precision), and what share of the labelled points have one
//! within that radius (recall). Not one-to-one: a detector that fires
//! twice on one junction scores both, as the radius-based measures of
//! corner detectors do.

use std::path::Path;

use datasets::DataError;

/// Labelled points of one image, in box coordinates (pixel (i, j) spans
/// [i, i + 1) x [j, j + 1)).
pub type Points = Vec<[f32; 2]>;

/// Reads a CSV whose first line is a header starting `x,y` and whose rows
/// start with two numbers in MATLAB's pixel convention (pixel centres at
/// integers from 1), as York Urban's `junctions_derived/*.csv`.
pub fn read_matlab_points(path: &Path) -> Result<Points, DataError> {
    let text = std::fs::read_to_string(path).map_err(|e| DataError::io(path, e))?;
    let mut lines = text.lines().enumerate();
    match lines.next() {
        Some((_, header)) if header.trim_start().starts_with("x,y") => {}
        _ => return Err(DataError::invalid(path, "no `x,y,...` header on the first line")),
    }
    let mut points = Vec::new();
    for (k, line) in lines {
        if line.trim().is_empty() {
            continue;
        }
        let mut fields = line.split(',');
        let mut number = |name: &str| -> Result<f32, DataError> {
            let field = fields.next().unwrap_or("").trim();
            field.parse::<f32>().ok().filter(|v| v.is_finite()).ok_or_else(|| {
                DataError::invalid(path, format!("line {}: {name} `{field}` is not a finite number", k + 1))
            })
        };
        let (x, y) = (number("x")?, number("y")?);
        // MATLAB's pixel 1 has its centre at 1; in box coordinates at 0.5.
        points.push([x - 0.5, y - 0.5]);
    }
    Ok(points)
}

/// Counts over one image or summed over many.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct PointScores {
    /// Points the method gave, and labelled points.
    pub points: usize,
    pub labels: usize,
    /// Points within the radius of some label.
    pub hits: usize,
    /// Labels with some point within the radius.
    pub found: usize,
}

impl PointScores {
    pub fn of(points: &[[f32; 2]], labels: &[[f32; 2]], radius: f32) -> Self {
        let near = |a: &[f32; 2], b: &[f32; 2]| (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) <= radius * radius;
        Self {
            points: points.len(),
            labels: labels.len(),
            hits: points.iter().filter(|p| labels.iter().any(|l| near(p, l))).count(),
            found: labels.iter().filter(|l| points.iter().any(|p| near(p, l))).count(),
        }
    }

    pub fn add(&mut self, other: &Self) {
        self.points += other.points;
        self.labels += other.labels;
        self.hits += other.hits;
        self.found += other.found;
    }

    /// `None` without points.
    pub fn precision(&self) -> Option<f64> {
        (self.points > 0).then(|| self.hits as f64 / self.points as f64)
    }

    /// `None` without labels.
    pub fn recall(&self) -> Option<f64> {
        (self.labels > 0).then(|| self.found as f64 / self.labels as f64)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn precision_and_recall_count_within_the_radius() {
        let labels = [[10.0, 10.0], [50.0, 50.0], [90.0, 10.0]];
        // Two on the first label (both count), one 12 px from the second
        // (in at 12, out at 11.9), one far from all.
        let points = [[11.0, 10.0], [9.0, 11.0], [50.0, 62.0], [200.0, 200.0]];
        let at12 = PointScores::of(&points, &labels, 12.0);
        assert_eq!(at12, PointScores { points: 4, labels: 3, hits: 3, found: 2 });
        assert_eq!(at12.precision(), Some(0.75));
        assert_eq!(at12.recall(), Some(2.0 / 3.0));
        let tighter = PointScores::of(&points, &labels, 11.9);
        assert_eq!((tighter.hits, tighter.found), (2, 1));
        let mut sum = at12;
        sum.add(&PointScores::of(&[], &labels, 12.0));
        assert_eq!((sum.points, sum.labels, sum.precision(), sum.recall()), (4, 6, Some(0.75), Some(2.0 / 6.0)));
        assert_eq!(PointScores::of(&[], &[], 12.0).precision(), None);
    }

    #[test]
    fn matlab_points_move_to_box_coordinates_and_bad_rows_are_named() {
        let dir = tempfile::tempdir().unwrap();
        let good = dir.path().join("good.csv");
        std::fs::write(&good, "x,y,type,seg_i,seg_j\n1,1,L,1,2\n248.44,279.72,T,1,14\n\n").unwrap();
        assert_eq!(read_matlab_points(&good).unwrap(), vec![[0.5, 0.5], [247.94, 279.22]]);
        let bad = dir.path().join("bad.csv");
        std::fs::write(&bad, "x,y,type\n1,2,L\n3,nan,T\n").unwrap();
        let message = read_matlab_points(&bad).unwrap_err().to_string();
        assert!(message.contains("bad.csv") && message.contains("line 3") && message.contains("y `nan`"), "{message}");
        let headless = dir.path().join("headless.csv");
        std::fs::write(&headless, "1,2\n").unwrap();
        assert!(read_matlab_points(&headless).unwrap_err().to_string().contains("header"));
    }

    #[test]
    fn york_urban_junctions_read_where_the_shared_data_is() {
        let path = Path::new(env!("CARGO_MANIFEST_DIR"))
            .join("../../shared/data/york_urban_lines/junctions_derived/P1020171.csv");
        if !path.is_file() {
            eprintln!("skipped: {} is not here", path.display());
            return;
        }
        let points = read_matlab_points(&path).unwrap();
        assert!(points.len() > 10, "{} junctions", points.len());
        assert!((points[0][0] - 247.94).abs() < 1e-4 && (points[0][1] - 279.22).abs() < 1e-4, "{:?}", points[0]);
        assert!(points.iter().all(|p| (0.0..640.0).contains(&p[0]) && (0.0..480.0).contains(&p[1])));
    }
}
