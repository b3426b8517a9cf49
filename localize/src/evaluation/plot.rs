//! The trajectory picture of a run: top view and height profile of the
//! fused estimate, the odometry/IMU reference and (when known) the truth.

use std::path::Path;

use datasets::io::formats::Trajectory;
use datasets::plot::{canvas, plot_error, register_font, write_png};
use plotters::prelude::*;

use crate::error::Result;

const WIDTH: u32 = 1400;
const HEIGHT: u32 = 620;

struct Curve<'a> {
    name: &'a str,
    trajectory: &'a Trajectory,
    colour: RGBColor,
}

fn range(values: impl Iterator<Item = f64>) -> (f64, f64) {
    values.fold((f64::MAX, f64::MIN), |(lo, hi), v| (lo.min(v), hi.max(v)))
}

/// Pads [lo, hi] by 5% and makes it at least `min_span` wide.
fn padded((lo, hi): (f64, f64), min_span: f64) -> (f64, f64) {
    let span = (hi - lo).max(min_span);
    let mid = 0.5 * (lo + hi);
    (mid - 0.55 * span, mid + 0.55 * span)
}

pub fn write_trajectory_png(
    path: &Path,
    fused: &Trajectory,
    reference: &Trajectory,
    truth: Option<&Trajectory>,
) -> Result<()> {
    register_font();
    let mut curves = Vec::new();
    if let Some(t) = truth {
        curves.push(Curve { name: "ground truth", trajectory: t, colour: RGBColor(0, 0, 0) });
    }
    curves.push(Curve { name: "odometry/IMU", trajectory: reference, colour: RGBColor(230, 120, 0) });
    curves.push(Curve { name: "fused (corners + planes)", trajectory: fused, colour: RGBColor(20, 90, 220) });
    let all = || curves.iter().flat_map(|c| c.trajectory.positions());
    let (mut xr, mut yr) = (padded(range(all().map(|p| p.x)), 1.0), padded(range(all().map(|p| p.y)), 1.0));
    // Equal scales on both axes of the top view (panel about 760 x 560 px).
    let aspect = 760.0 / 560.0;
    let (wx, wy) = (xr.1 - xr.0, yr.1 - yr.0);
    if wx / wy < aspect {
        let grow = (wy * aspect - wx) / 2.0;
        xr = (xr.0 - grow, xr.1 + grow);
    } else {
        let grow = (wx / aspect - wy) / 2.0;
        yr = (yr.0 - grow, yr.1 + grow);
    }
    let zr = padded(range(all().map(|p| p.z)), 0.2);
    let tr = range(curves.iter().flat_map(|c| c.trajectory.stamps.iter().copied()));
    let mut pixels = canvas(WIDTH, HEIGHT);
    {
        let root = BitMapBackend::with_buffer(&mut pixels, (WIDTH, HEIGHT)).into_drawing_area();
        root.fill(&WHITE).map_err(|e| plot_error(path, e))?;
        let (left, right) = root.split_horizontally(820);
        let mut top = ChartBuilder::on(&left)
            .caption("top view", ("sans-serif", 22))
            .margin(14)
            .x_label_area_size(40)
            .y_label_area_size(55)
            .build_cartesian_2d(xr.0..xr.1, yr.0..yr.1)
            .map_err(|e| plot_error(path, e))?;
        top.configure_mesh().x_desc("x (m)").y_desc("y (m)").draw().map_err(|e| plot_error(path, e))?;
        for c in &curves {
            let colour = c.colour;
            top.draw_series(LineSeries::new(c.trajectory.positions().map(|p| (p.x, p.y)), colour.stroke_width(2)))
                .map_err(|e| plot_error(path, e))?
                .label(c.name)
                .legend(move |(x, y)| PathElement::new(vec![(x, y), (x + 24, y)], colour.stroke_width(3)));
        }
        top.configure_series_labels()
            .position(SeriesLabelPosition::UpperLeft)
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .label_font(("sans-serif", 16))
            .draw()
            .map_err(|e| plot_error(path, e))?;
        let mut side = ChartBuilder::on(&right)
            .caption("height", ("sans-serif", 22))
            .margin(14)
            .x_label_area_size(40)
            .y_label_area_size(55)
            .build_cartesian_2d(tr.0..tr.1.max(tr.0 + 1.0), zr.0..zr.1)
            .map_err(|e| plot_error(path, e))?;
        side.configure_mesh().x_desc("time (s)").y_desc("z (m)").draw().map_err(|e| plot_error(path, e))?;
        for c in &curves {
            let points = c.trajectory.stamps.iter().zip(c.trajectory.positions()).map(|(t, p)| (*t, p.z));
            side.draw_series(LineSeries::new(points, c.colour.stroke_width(2))).map_err(|e| plot_error(path, e))?;
        }
        root.present().map_err(|e| plot_error(path, e))?;
    }
    Ok(write_png(path, WIDTH, HEIGHT, pixels)?)
}
