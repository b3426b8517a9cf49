//! The synthetic multilevel world and its sensors ([`world`]), and the
//! writers of the project's default data made from it: the detection data set
//! and the localization sequence ([`generate`]), and the training corpus of
//! many buildings ([`corpus`]). Depends on the shared layer and [`crate::io`].

pub mod corpus;
pub mod generate;
pub mod world;
