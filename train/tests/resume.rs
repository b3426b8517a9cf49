//! An interrupted run resumes to the same losses as an uninterrupted one.
//! Alone in its test binary: Burn's CPU backend draws weights and dropout
//! masks from one process-wide generator, which parallel tests would share.

mod common;

use common::{tiny_config, train_losses};
use infer::config::Backbone;

#[test]
fn an_interrupted_run_resumes_to_the_same_losses() {
    let whole = tempfile::tempdir().unwrap();
    train::train(Some(tiny_config(Backbone::Alexnet, 3)), whole.path(), false).unwrap();
    // The same run interrupted after its first epoch, then resumed.
    let parts = tempfile::tempdir().unwrap();
    let stopped =
        train::trainer::train_until(Some(tiny_config(Backbone::Alexnet, 3)), parts.path(), false, Some(1)).unwrap();
    assert!(stopped.is_none());
    assert_eq!(train_losses(parts.path()).len(), 2, "one epoch of two iterations logged");
    train::train(None, parts.path(), false).unwrap();
    let (a, b) = (train_losses(whole.path()), train_losses(parts.path()));
    assert_eq!(a.len(), b.len());
    for (k, (x, y)) in a.iter().zip(&b).enumerate() {
        assert_eq!(x, y, "iteration {k}: uninterrupted vs resumed (the log keeps 6 decimals)");
    }
}
