//! The transform tree of a recording: `/tf_static` edges, and `/tf` edges
//! (their first reading) for chains that need a dynamic link. Lookups walk
//! the tree in either direction.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use crate::io::recording::messages::geometry::Transform;
use crate::math::Pose3;

#[derive(Debug, Clone, Default)]
pub struct TfTree {
    /// parent -> child -> parent_from_child; static edges win over dynamic ones.
    edges: BTreeMap<(String, String), (Pose3, bool)>,
    /// Static edges given again with another pose: what was kept and how far the other was.
    conflicts: Vec<String>,
}

/// A static edge given again within these of the first is the same edge.
const SAME_EDGE_M: f64 = 1e-3;
const SAME_EDGE_DEG: f64 = 0.1;

/// `frame_id`s are compared without a leading `/` (ROS 1 wrote `/base_link`).
fn frame(name: &str) -> String {
    name.trim_start_matches('/').to_string()
}

impl TfTree {
    pub fn add(&mut self, transform: &Transform, is_static: bool) {
        let key = (frame(&transform.header.frame_id), frame(&transform.child_frame_id));
        match self.edges.get(&key) {
            Some((kept, true)) => {
                let apart_m = (kept.translation.vector - transform.parent_from_child.translation.vector).norm();
                let apart_deg = kept.rotation.angle_to(&transform.parent_from_child.rotation).to_degrees();
                if is_static && !(apart_m <= SAME_EDGE_M && apart_deg <= SAME_EDGE_DEG) {
                    self.conflicts.push(format!(
                        "{} -> {} given twice, {apart_m:.3} m and {apart_deg:.2} degrees apart: the first is used",
                        key.0, key.1
                    ));
                }
            }
            Some((_, false)) if !is_static => {}
            _ => {
                self.edges.insert(key, (transform.parent_from_child, is_static));
            }
        }
    }

    pub fn is_empty(&self) -> bool {
        self.edges.is_empty()
    }

    /// Static edges the recording gave again with another pose.
    pub fn conflicts(&self) -> &[String] {
        &self.conflicts
    }

    pub fn frames(&self) -> BTreeSet<String> {
        self.edges.keys().flat_map(|(a, b)| [a.clone(), b.clone()]).collect()
    }

    /// `target_from_source`, through static edges and, where `dynamic`,
    /// the first reading of dynamic ones; `None` when no chain joins them.
    pub fn lookup(&self, target: &str, source: &str, dynamic: bool) -> Option<Pose3> {
        let (target, source) = (frame(target), frame(source));
        if target == source {
            return Some(Pose3::identity());
        }
        // Breadth-first from the source; each visited frame holds source-to-it.
        let mut found: BTreeMap<String, Pose3> = BTreeMap::new();
        found.insert(source.clone(), Pose3::identity());
        let mut queue = VecDeque::from([source]);
        while let Some(at) = queue.pop_front() {
            // at_from_source is known; step to a neighbour n: n_from_source.
            let at_from_source = found[&at];
            for ((parent, child), (parent_from_child, is_static)) in &self.edges {
                if !is_static && !dynamic {
                    continue;
                }
                let step = if *child == at {
                    Some((parent, parent_from_child * at_from_source))
                } else if *parent == at {
                    Some((child, parent_from_child.inverse() * at_from_source))
                } else {
                    None
                };
                if let Some((next, next_from_source)) = step
                    && !found.contains_key(next)
                {
                    found.insert(next.clone(), next_from_source);
                    queue.push_back(next.clone());
                }
            }
        }
        found.get(&target).copied()
    }
}

#[cfg(test)]
mod conflict_tests {
    use super::*;
    use crate::io::recording::wire::Header;
    use crate::math::Vec3;

    fn edge(x: f64, yaw: f64) -> Transform {
        Transform {
            header: Header { stamp_ns: 0, frame_id: "/base_link".into() },
            child_frame_id: "lidar".into(),
            parent_from_child: Pose3::new(Vec3::new(x, 0.0, 0.3), Vec3::new(0.0, 0.0, yaw)),
        }
    }

    #[test]
    fn a_static_edge_given_again_elsewhere_is_reported_and_the_first_kept() {
        let mut tree = TfTree::default();
        tree.add(&edge(0.1, 0.0), true);
        tree.add(&edge(0.1 + 1e-4, 0.0), true);
        assert!(tree.conflicts().is_empty(), "the same edge again, within a tenth of a millimetre");
        tree.add(&edge(0.3, 0.05), true);
        assert_eq!(tree.conflicts().len(), 1);
        assert!(tree.conflicts()[0].contains("base_link -> lidar given twice, 0.200 m and 2.86 degrees apart"));
        let kept = tree.lookup("base_link", "lidar", false).unwrap();
        assert!((kept.translation.vector.x - 0.1).abs() < 1e-12, "the first is used");
        // A dynamic edge does not conflict with a static one.
        tree.add(&edge(0.5, 0.0), false);
        assert_eq!(tree.conflicts().len(), 1);
    }
}
