//! The transform tree of a recording: `/tf_static` edges, and `/tf` edges
//! (their first reading) for chains that need a dynamic link. Lookups walk
//! the tree in either direction.

use std::collections::{BTreeMap, BTreeSet, VecDeque};

use crate::math::Pose3;
use crate::recording::messages::geometry::Transform;

#[derive(Debug, Clone, Default)]
pub struct TfTree {
    /// parent -> child -> parent_from_child; static edges win over dynamic ones.
    edges: BTreeMap<(String, String), (Pose3, bool)>,
}

/// `frame_id`s are compared without a leading `/` (ROS 1 wrote `/base_link`).
fn frame(name: &str) -> String {
    name.trim_start_matches('/').to_string()
}

impl TfTree {
    pub fn add(&mut self, transform: &Transform, is_static: bool) {
        let key = (frame(&transform.header.frame_id), frame(&transform.child_frame_id));
        match self.edges.get(&key) {
            Some((_, true)) => {}
            Some((_, false)) if !is_static => {}
            _ => {
                self.edges.insert(key, (transform.parent_from_child, is_static));
            }
        }
    }

    pub fn is_empty(&self) -> bool {
        self.edges.is_empty()
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
