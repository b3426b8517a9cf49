//! Generated buildings: building N >= 1 is drawn from N alone. Three or four
//! halls in a row, each one level or split by a ramp across it, joined by
//! straight or Z-shaped corridors that may climb a ramp; 2 to 4 levels with
//! ramps of 4 to 12 degrees; side rooms behind doorways; pillars and
//! partitions at any angle, glass panes, crates, tables, chairs and shelves;
//! people pacing in the halls. The route loops round every hall and room on
//! the way out and comes back through every hall to where it started, so it
//! revisits places and changes level on the way out and back.
//!
//! Layout rules that keep every building valid: halls and corridors follow
//! one another along +x, rooms hang off a hall's long sides within its x
//! range, and every region touches only the regions it opens onto.

use rand::rngs::ChaCha8Rng;
use rand::{RngExt, SeedableRng};

use super::block::{Block, BlockKind};
use super::layout::{Axis, Floor, Layout, Region, WorldConfig};
use super::people::Walker;
use super::route::{Route, TRACK_M, WHEELBASE_M, samples_on_floor};
use crate::seed::mix;

/// The largest building number accepted.
pub const MAX_BUILDING: u32 = 1_000_000;

/// Turn radius the route is checked with (the sequence's default).
const TURN_RADIUS_M: f64 = 1.2;
/// Distance of a hall's loop from its walls.
const LOOP_INSET_M: f64 = 1.6;
/// Route lengths a building's route must fall in.
const ROUTE_LENGTH_M: [f64; 2] = [100.0, 300.0];

/// Building `number` (>= 1); `appearance_seed` varies colours and posters.
pub fn generate(number: u32, appearance_seed: u64) -> Layout {
    let mut simple = false;
    for attempt in 0u64.. {
        // Rooms and furniture make most of the failed draws; after many,
        // draw without them so that every number gives a building.
        simple |= attempt >= 64;
        let mut rng = ChaCha8Rng::seed_from_u64(mix(mix(u64::from(number) ^ 0xb1d6) ^ attempt));
        if let Some(mut layout) = Plan::draw(&mut rng, number, simple) {
            layout.build_surfaces_and_corners(appearance_seed);
            return layout;
        }
    }
    unreachable!("the attempts never end")
}

/// One hall: its x range, y range, and where a ramp across it runs (x range).
#[derive(Debug, Clone, Copy)]
struct Hall {
    x: [f64; 2],
    y: [f64; 2],
    ramp: Option<[f64; 2]>,
    /// Floor heights of its lower (west) and upper (east) parts.
    floors: [f64; 2],
    levels: [usize; 2],
}

impl Hall {
    /// The flat parts: (x range, floor height, level).
    fn parts(&self) -> Vec<([f64; 2], f64, usize)> {
        match self.ramp {
            None => vec![(self.x, self.floors[0], self.levels[0])],
            Some([a, b]) => {
                vec![([self.x[0], a], self.floors[0], self.levels[0]), ([b, self.x[1]], self.floors[1], self.levels[1])]
            }
        }
    }
}

struct Plan<'r> {
    rng: &'r mut ChaCha8Rng,
    regions: Vec<Region>,
    /// Ceiling height above the floor, the same everywhere.
    ceiling_m: f64,
    levels: Vec<f64>,
}

impl<'r> Plan<'r> {
    fn draw(rng: &'r mut ChaCha8Rng, number: u32, simple: bool) -> Option<Layout> {
        let ceiling_m = rng.random_range(2.8..3.6);
        let mut plan = Plan { rng, regions: Vec::new(), ceiling_m, levels: vec![0.0] };
        let level_count = plan.rng.random_range(2..=4usize);
        let hall_count = plan.rng.random_range(3..=4usize);
        // Slots for level changes: even = inside hall k/2, odd = the corridor after it.
        let changes = plan.change_slots(level_count - 1, hall_count);

        let mut halls: Vec<Hall> = Vec::new();
        let mut forward: Vec<[f64; 2]> = Vec::new();
        // Between consecutive halls: the exit y, the corridor's turning
        // points and the next hall's entry y.
        let mut corridors: Vec<(f64, Vec<[f64; 2]>, f64)> = Vec::new();
        let mut entry_y = 0.0;
        let mut x0 = -LOOP_INSET_M;
        for k in 0..hall_count {
            let hall = plan.hall(k, x0, entry_y, changes.contains(&(2 * k)));
            halls.push(hall);
            let m = LOOP_INSET_M;
            let [hx0, hx1] = hall.x;
            let [hy0, hy1] = hall.y;
            let (bl, br, tr, tl) = ([hx0 + m, hy0 + m], [hx1 - m, hy0 + m], [hx1 - m, hy1 - m], [hx0 + m, hy1 - m]);
            let entry = [hx0 + m, entry_y];
            if k == 0 {
                forward.push(bl);
            } else {
                forward.push(entry);
                forward.push(bl);
            }
            if !simple {
                plan.room(&hall, false, &mut forward, bl[1]);
            }
            forward.push(br);
            forward.push(tr);
            if !simple {
                plan.room(&hall, true, &mut forward, tl[1]);
            }
            forward.push(tl);
            if k + 1 < hall_count {
                if k > 0 {
                    forward.push(entry);
                }
                let exit_y = plan.rng.random_range(hy0 + m + 1.5..hy1 - m - 1.5);
                forward.push([hx1 - m, exit_y]);
                let (points, next_x0, next_entry_y) = plan.corridor(&hall, exit_y, changes.contains(&(2 * k + 1)));
                forward.extend(points.iter().copied());
                corridors.push((exit_y, points, next_entry_y));
                x0 = next_x0;
                entry_y = next_entry_y;
            } else if k > 0 {
                forward.push(entry);
            }
        }
        let route = round_trip(forward, &halls, &corridors);

        let config = WorldConfig { building: number, ..WorldConfig::default() };
        let regions = std::mem::take(&mut plan.regions);
        let mut layout = Layout::unbuilt(config, plan.levels.clone(), regions, Vec::new(), route);
        let samples = route_samples(&layout)?;
        let length = Route::new(&layout.route, TURN_RADIUS_M).length();
        if !(ROUTE_LENGTH_M[0]..=ROUTE_LENGTH_M[1]).contains(&length) {
            return None;
        }
        if !simple {
            plan.furnish(&mut layout, &halls, &samples);
        }
        plan.people(&mut layout, &halls);
        Some(layout)
    }

    /// `count` distinct level-change slots among `halls` halls and the
    /// corridors between them, with at least one inside a hall and, when
    /// there are two or more, one in a corridor.
    fn change_slots(&mut self, count: usize, halls: usize) -> Vec<usize> {
        let hall_slots: Vec<usize> = (0..halls).map(|k| 2 * k).collect();
        let corridor_slots: Vec<usize> = (0..halls - 1).map(|k| 2 * k + 1).collect();
        let mut chosen = vec![hall_slots[self.rng.random_range(0..hall_slots.len())]];
        if count >= 2 {
            chosen.push(corridor_slots[self.rng.random_range(0..corridor_slots.len())]);
        }
        while chosen.len() < count {
            let slot = self.rng.random_range(0..2 * halls - 1);
            if !chosen.contains(&slot) {
                chosen.push(slot);
            }
        }
        chosen
    }

    /// A ramp's slope and run: rise = run x tan(slope).
    fn ramp(&mut self, runs: std::ops::Range<f64>) -> (f64, f64) {
        let slope = self.rng.random_range(4f64..12.0).to_radians();
        let run = self.rng.random_range(runs);
        (run, run * slope.tan())
    }

    fn current_level(&self) -> (usize, f64) {
        (self.levels.len() - 1, *self.levels.last().expect("one level at least"))
    }

    fn push_region(&mut self, name: String, x: [f64; 2], y: [f64; 2], floor: Floor, level: Option<usize>) {
        self.regions.push(Region { name, x, y, floor, level, ceiling_m: Some(self.ceiling_m) });
    }

    /// Hall `k` from `x0`, holding `entry_y` well inside its y range.
    fn hall(&mut self, k: usize, x0: f64, entry_y: f64, with_ramp: bool) -> Hall {
        let m = LOOP_INSET_M;
        let (lo_level, lo_floor) = self.current_level();
        let (x, depth, ramp) = if with_ramp {
            let lower = self.rng.random_range(4.5..6.5);
            let (run, rise) = self.ramp(4.0..7.0);
            let upper = self.rng.random_range(4.5..6.5);
            self.levels.push(lo_floor + rise);
            ([x0, x0 + lower + run + upper], self.rng.random_range(6.5..10.0), Some([x0 + lower, x0 + lower + run]))
        } else {
            ([x0, x0 + self.rng.random_range(9.0..15.0)], self.rng.random_range(7.0..12.0), None)
        };
        // The entry sits at least a loop inset plus 1.5 m from the side
        // walls; the first hall's loop starts at the origin.
        let slack = depth - 2.0 * (m + 1.5);
        let below = if k == 0 { m } else { m + 1.5 + self.rng.random_range(0.0..slack.max(1e-6)) };
        let y = [entry_y - below, entry_y - below + depth];
        let (hi_level, hi_floor) = self.current_level();
        let name = |part: &str| format!("level {} hall {}{part}", lo_level + 1, k + 1);
        match ramp {
            None => self.push_region(name(""), x, y, Floor::Flat { height_m: lo_floor }, Some(lo_level)),
            Some([a, b]) => {
                self.push_region(name(" west"), [x[0], a], y, Floor::Flat { height_m: lo_floor }, Some(lo_level));
                let floor = Floor::Ramp { axis: Axis::X, from: a, to: b, h0: lo_floor, h1: hi_floor };
                self.push_region(format!("ramp in hall {}", k + 1), [a, b], y, floor, None);
                let upper = format!("level {} hall {} east", hi_level + 1, k + 1);
                self.push_region(upper, [b, x[1]], y, Floor::Flat { height_m: hi_floor }, Some(hi_level));
            }
        }
        Hall { x, y, ramp, floors: [lo_floor, hi_floor], levels: [lo_level, hi_level] }
    }

    /// The corridor from `hall`'s east side at `exit_y`: its centre-line
    /// points, the next hall's west x and its entry y.
    fn corridor(&mut self, hall: &Hall, exit_y: f64, with_ramp: bool) -> (Vec<[f64; 2]>, f64, f64) {
        let width = self.rng.random_range(1.8..2.6);
        let start = CorridorStart { x1: hall.x[1], exit_y, width, index: self.regions.len() };
        if self.rng.random_bool(0.5) {
            self.straight_corridor(&start, with_ramp)
        } else {
            self.z_corridor(&start, with_ramp)
        }
    }

    /// Straight along x, the ramp (if any) between two flat ends.
    fn straight_corridor(&mut self, start: &CorridorStart, with_ramp: bool) -> (Vec<[f64; 2]>, f64, f64) {
        let CorridorStart { x1, exit_y, width, index } = *start;
        let w = width / 2.0;
        let (level, floor) = self.current_level();
        let flat = |h: f64| Floor::Flat { height_m: h };
        let name = |what: &str| format!("corridor {index} {what}");
        if with_ramp {
            let (run, rise) = self.ramp(4.0..9.0);
            self.levels.push(floor + rise);
            let (a, b) = (x1 + 1.5, x1 + 1.5 + run);
            let next = b + 1.5;
            self.push_region(name("west"), [x1, a], [exit_y - w, exit_y + w], flat(floor), Some(level));
            let ramp = Floor::Ramp { axis: Axis::X, from: a, to: b, h0: floor, h1: floor + rise };
            self.push_region(name("ramp"), [a, b], [exit_y - w, exit_y + w], ramp, None);
            self.push_region(name("east"), [b, next], [exit_y - w, exit_y + w], flat(floor + rise), Some(level + 1));
            (Vec::new(), next, exit_y)
        } else {
            let next = x1 + self.rng.random_range(3.0..7.0);
            self.push_region(name(""), [x1, next], [exit_y - w, exit_y + w], flat(floor), Some(level));
            (Vec::new(), next, exit_y)
        }
    }

    /// Z-shaped: east, north or south (climbing a ramp if any), east.
    fn z_corridor(&mut self, start: &CorridorStart, with_ramp: bool) -> (Vec<[f64; 2]>, f64, f64) {
        let CorridorStart { x1, exit_y, width, index } = *start;
        let w = width / 2.0;
        let (level, floor) = self.current_level();
        let flat = |h: f64| Floor::Flat { height_m: h };
        let name = |what: &str| format!("corridor {index} {what}");
        let sign = if self.rng.random_bool(0.5) { 1.0 } else { -1.0 };
        let xm = x1 + self.rng.random_range(2.5..5.0);
        let next = xm + self.rng.random_range(2.5..5.0);
        let (run, rise) = if with_ramp { self.ramp(4.0..8.0) } else { (0.0, 0.0) };
        let span = if with_ramp {
            width + 2.0 + run + self.rng.random_range(0.0..2.0)
        } else {
            self.rng.random_range(3.0..8.0)
        };
        let entry_y = exit_y + sign * span;
        let ys = |a: f64, b: f64| [a.min(b), a.max(b)];
        self.push_region(name("west"), [x1, xm + w], [exit_y - w, exit_y + w], flat(floor), Some(level));
        let (upper_level, upper_floor) = if with_ramp {
            self.levels.push(floor + rise);
            let a = exit_y + sign * (w + 1.0);
            let b = a + sign * run;
            self.push_region(name("north-south"), [xm - w, xm + w], ys(exit_y - sign * w, a), flat(floor), Some(level));
            let [from, to] = ys(a, b);
            let (h0, h1) = if sign > 0.0 { (floor, floor + rise) } else { (floor + rise, floor) };
            self.push_region(
                name("ramp"),
                [xm - w, xm + w],
                [from, to],
                Floor::Ramp { axis: Axis::Y, from, to, h0, h1 },
                None,
            );
            self.push_region(
                name("north-south end"),
                [xm - w, xm + w],
                ys(b, entry_y + sign * w),
                flat(floor + rise),
                Some(level + 1),
            );
            (level + 1, floor + rise)
        } else {
            self.push_region(
                name("north-south"),
                [xm - w, xm + w],
                ys(exit_y - sign * w, entry_y + sign * w),
                flat(floor),
                Some(level),
            );
            (level, floor)
        };
        self.push_region(
            name("east"),
            [xm - w, next],
            [entry_y - w, entry_y + w],
            flat(upper_floor),
            Some(upper_level),
        );
        (vec![[xm, exit_y], [xm, entry_y]], next, entry_y)
    }

    /// Maybe a side room behind a doorway in `hall`'s north (`north`) or
    /// south wall, visited from the loop edge at `edge_y` with a small loop
    /// of its own.
    fn room(&mut self, hall: &Hall, north: bool, route: &mut Vec<[f64; 2]>, edge_y: f64) {
        if !self.rng.random_bool(0.6) {
            return;
        }
        let m = LOOP_INSET_M;
        let width = self.rng.random_range(4.4..6.0);
        let depth = self.rng.random_range(3.6..5.0);
        let wall = 0.3;
        // A door over a flat part, the room inside the hall's x range.
        let parts = hall.parts();
        let (part_x, floor, level) = parts[self.rng.random_range(0..parts.len())];
        let lo = (part_x[0] + 0.7).max(hall.x[0] + m + 1.3).max(hall.x[0] + 1.5);
        let hi = (part_x[1] - 0.7).min(hall.x[1] - m - 3.5).min(hall.x[1] - width + 1.0);
        if hi <= lo {
            return;
        }
        let dx = self.rng.random_range(lo..hi);
        let room_x = [dx - 1.2, dx - 1.2 + width];
        let (door_y, room_y, ya, yb) = if north {
            let y1 = hall.y[1];
            ([y1, y1 + wall], [y1 + wall, y1 + wall + depth], y1 + wall + 1.0, y1 + wall + depth - 1.0)
        } else {
            let y0 = hall.y[0];
            ([y0 - wall, y0], [y0 - wall - depth, y0 - wall], y0 - wall - 1.0, y0 - wall - depth + 1.0)
        };
        let flat = Floor::Flat { height_m: floor };
        let n = self.regions.len();
        self.push_region(format!("level {} doorway {n}", level + 1), [dx - 0.5, dx + 0.5], door_y, flat, Some(level));
        self.push_region(format!("level {} room {n}", level + 1), room_x, room_y, flat, Some(level));
        route.extend([[dx, edge_y], [dx, ya], [dx + 2.2, ya], [dx + 2.2, yb], [dx, yb], [dx, ya], [dx, edge_y]]);
    }

    /// Pillars, partitions, glass, crates and furniture in the halls and
    /// rooms, clear of the route.
    fn furnish(&mut self, layout: &mut Layout, halls: &[Hall], samples: &[[f64; 2]]) {
        let h = self.ceiling_m;
        let mut areas: Vec<([f64; 2], [f64; 2], f64, bool)> = Vec::new();
        for hall in halls {
            for (x, floor, _) in hall.parts() {
                areas.push((x, hall.y, floor, true));
            }
        }
        for r in &layout.regions {
            if r.name.contains(" room ")
                && let Floor::Flat { height_m } = r.floor
            {
                areas.push((r.x, r.y, height_m, false));
            }
        }
        for (x, y, floor, is_hall) in areas {
            let area = (x[1] - x[0]) * (y[1] - y[0]);
            let mut wanted: Vec<(BlockKind, [f64; 2], f64)> = Vec::new();
            let count =
                |rng: &mut ChaCha8Rng, per_m2: f64| (area * per_m2 * rng.random_range(0.5..1.5)).round() as usize;
            if is_hall {
                for _ in 0..count(self.rng, 0.03).max(1) {
                    let side = self.rng.random_range(0.18..0.28);
                    wanted.push((BlockKind::Pillar, [side, side], h));
                }
                for _ in 0..count(self.rng, 0.012).max(1) {
                    wanted.push((BlockKind::Partition, [self.rng.random_range(0.6..1.4), 0.06], h));
                }
                for _ in 0..count(self.rng, 0.01).max(1) {
                    wanted.push((BlockKind::Glass, [self.rng.random_range(0.6..1.3), 0.01], h));
                }
            }
            for _ in 0..count(self.rng, 0.03) {
                let half = [self.rng.random_range(0.2..0.45), self.rng.random_range(0.2..0.45)];
                wanted.push((BlockKind::Crate, half, self.rng.random_range(0.4..1.0)));
            }
            for _ in 0..count(self.rng, 0.025) {
                wanted.push((
                    BlockKind::Table,
                    [self.rng.random_range(0.4..0.8), self.rng.random_range(0.3..0.45)],
                    0.75,
                ));
            }
            for _ in 0..count(self.rng, 0.05) {
                wanted.push((BlockKind::Chair, [0.22, 0.22], 0.9));
            }
            for _ in 0..count(self.rng, 0.02) {
                wanted.push((
                    BlockKind::Shelf,
                    [self.rng.random_range(0.4..0.6), 0.18],
                    self.rng.random_range(1.4..2.0),
                ));
            }
            for (kind, half, height) in wanted {
                self.place(layout, samples, (x, y, floor), kind, half, height);
            }
        }
    }

    /// Up to 60 tries to place a block of `kind` (half sizes `half`, height
    /// `height`) in the area `x` by `y` at floor height `floor`, clear of the
    /// route, of the other blocks and of the area's walls.
    fn place(
        &mut self,
        layout: &mut Layout,
        samples: &[[f64; 2]],
        (x, y, floor): ([f64; 2], [f64; 2], f64),
        kind: BlockKind,
        half: [f64; 2],
        height: f64,
    ) {
        for _ in 0..60 {
            let yaw = if self.rng.random_bool(0.5) {
                self.rng.random_range(0.0..std::f64::consts::PI)
            } else {
                f64::from(self.rng.random_range(0..4u8)) * std::f64::consts::FRAC_PI_2
            };
            let r = half[0].hypot(half[1]) + 0.1;
            if x[1] - x[0] <= 2.0 * r || y[1] - y[0] <= 2.0 * r {
                break;
            }
            let centre = [self.rng.random_range(x[0] + r..x[1] - r), self.rng.random_range(y[0] + r..y[1] - r)];
            let block = Block { kind, centre, half, yaw, z: [floor, floor + height] };
            let clearance = 0.8;
            let clear_of_route = samples.iter().all(|&p| block.distance(p) > clearance);
            let clear_of_blocks = layout.blocks.iter().all(|b| {
                let d = (b.centre[0] - centre[0]).hypot(b.centre[1] - centre[1]);
                d > b.radius() + block.radius() + 0.15
            });
            // The whole footprint in this area, never across a wall.
            let on_floor = block
                .footprint()
                .iter()
                .all(|p| p[0] > x[0] + 0.05 && p[0] < x[1] - 0.05 && p[1] > y[0] + 0.05 && p[1] < y[1] - 0.05);
            if clear_of_route && clear_of_blocks && on_floor {
                layout.blocks.push(block);
                break;
            }
        }
    }

    /// One or two people pacing in every hall's flat parts.
    fn people(&mut self, layout: &mut Layout, halls: &[Hall]) {
        for hall in halls {
            for (x, floor, _) in hall.parts() {
                for _ in 0..self.rng.random_range(1..=2usize) {
                    let along_x = self.rng.random_bool(0.5);
                    let (from, to) = if along_x {
                        let y = self.rng.random_range(hall.y[0] + 0.6..hall.y[1] - 0.6);
                        ([x[0] + 0.5, y], [x[1] - 0.5, y])
                    } else {
                        let xm = self.rng.random_range(x[0] + 0.6..x[1] - 0.6);
                        ([xm, hall.y[0] + 0.5], [xm, hall.y[1] - 0.5])
                    };
                    let colour = std::array::from_fn(|_| self.rng.random_range(0.1f32..0.8));
                    layout.walkers.push(Walker {
                        from,
                        to,
                        floor_m: floor,
                        speed_mps: self.rng.random_range(0.8..1.4),
                        phase_m: self.rng.random_range(0.0..20.0),
                        height_m: self.rng.random_range(1.6..1.85),
                        colour,
                    });
                }
            }
        }
    }
}

/// Points along the route every 5 cm, or `None` where the robot would leave
/// the free space (a wheel off every region).
fn route_samples(layout: &Layout) -> Option<Vec<[f64; 2]>> {
    let route = Route::new(&layout.route, TURN_RADIUS_M);
    let samples = samples_on_floor(layout, &route, 0.05).ok()?;
    let margin = (WHEELBASE_M.hypot(TRACK_M)) / 2.0 + 0.15;
    // The body, not only the wheels, stays off the walls.
    for ([x, y], _) in &samples {
        for a in 0..8 {
            let angle = a as f64 * std::f64::consts::FRAC_PI_4;
            layout.floor_height(x + margin * angle.cos(), y + margin * angle.sin())?;
        }
    }
    Some(samples.into_iter().map(|(xy, _)| xy).collect())
}

/// The route out (`forward`) and back through every corridor and hall to
/// the start; `corridors` as `Plan::draw` gathers them.
fn round_trip(forward: Vec<[f64; 2]>, halls: &[Hall], corridors: &[(f64, Vec<[f64; 2]>, f64)]) -> Vec<[f64; 2]> {
    let mut route = forward;
    for k in (0..halls.len() - 1).rev() {
        let (exit_y, points, _) = &corridors[k];
        route.extend(points.iter().rev().copied());
        let hall = &halls[k];
        route.push([hall.x[1] - LOOP_INSET_M, *exit_y]);
        if k > 0 {
            route.push([hall.x[0] + LOOP_INSET_M, corridors[k - 1].2]);
        }
    }
    route.push([0.0, 0.0]);
    route.dedup_by(|a, b| (a[0] - b[0]).abs() < 1e-9 && (a[1] - b[1]).abs() < 1e-9);
    route
}

/// Where a corridor leaves its hall: the hall's east x, the exit's y, the
/// corridor's width and the index of its first region (for its names).
#[derive(Clone, Copy)]
struct CorridorStart {
    x1: f64,
    exit_y: f64,
    width: f64,
    index: usize,
}
