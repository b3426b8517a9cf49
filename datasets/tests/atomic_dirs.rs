//! Folders written as a unit survive a kill at any point: the state renamed
//! aside between the two renames comes back, leftovers go.

use datasets::atomic::{recover_dir, remove_leftovers, write_dir};

#[test]
fn a_folder_renamed_aside_by_a_kill_comes_back_and_leftovers_go() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("resume");
    write_dir::<datasets::DataError>(&dir, |tmp| {
        std::fs::write(tmp.join("state.json"), "1").unwrap();
        Ok(())
    })
    .unwrap();
    // Killed after `resume` became `.old-resume`, before the new one moved in.
    std::fs::rename(&dir, root.path().join(".old-resume")).unwrap();
    assert!(recover_dir(&dir).unwrap());
    assert_eq!(std::fs::read_to_string(dir.join("state.json")).unwrap(), "1");
    assert!(!recover_dir(&dir).unwrap(), "nothing to recover twice");
    // With both present the newer folder stays; write_dir recovers first.
    std::fs::rename(&dir, root.path().join(".old-resume")).unwrap();
    write_dir::<datasets::DataError>(&dir, |tmp| {
        std::fs::write(tmp.join("state.json"), "2").unwrap();
        Ok(())
    })
    .unwrap();
    assert_eq!(std::fs::read_to_string(dir.join("state.json")).unwrap(), "2");
    assert!(!root.path().join(".old-resume").exists());
    std::fs::create_dir(root.path().join(".tmp-dir-x")).unwrap();
    std::fs::write(root.path().join(".tmp-y"), "").unwrap();
    std::fs::write(root.path().join("keep.tmp"), "").unwrap();
    assert_eq!(remove_leftovers(root.path()).unwrap(), 2);
    let mut names: Vec<_> =
        std::fs::read_dir(root.path()).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
    names.sort();
    assert_eq!(names, ["keep.tmp", "resume"]);
}

#[test]
fn a_killed_write_leaves_a_sibling_that_the_next_write_of_the_same_target_removes() {
    let root = tempfile::tempdir().unwrap();
    let dir = root.path().join("run");
    // What kills of earlier writes left: one of `run`, one of `run-2`, one of a bag.
    for name in [".tmp-run.~Ab12Cd", ".tmp-run-2.~Ab12Cd", ".tmp-bag.mcap.~Zz9Yy8.mcap"] {
        std::fs::create_dir(root.path().join(name)).unwrap();
    }
    write_dir::<datasets::DataError>(&dir, |tmp| {
        assert!(tmp.file_name().unwrap().to_string_lossy().starts_with(".tmp-run.~"));
        std::fs::write(tmp.join("trajectory.txt"), "1").unwrap();
        Ok(())
    })
    .unwrap();
    let names = |root: &std::path::Path| {
        let mut names: Vec<_> =
            std::fs::read_dir(root).unwrap().map(|e| e.unwrap().file_name().into_string().unwrap()).collect();
        names.sort();
        names
    };
    assert_eq!(names(root.path()), [".tmp-bag.mcap.~Zz9Yy8.mcap", ".tmp-run-2.~Ab12Cd", "run"]);
    let bag = root.path().join("bag.mcap");
    assert_eq!(datasets::atomic::remove_stale_siblings(&bag, ".mcap").unwrap(), 1);
    assert_eq!(names(root.path()), [".tmp-run-2.~Ab12Cd", "run"]);
}

#[cfg(unix)]
#[test]
fn a_link_loop_and_a_dangling_link_are_named_as_what_they_are() {
    let dir = tempfile::tempdir().unwrap();
    let looped = dir.path().join("loop.bag");
    std::os::unix::fs::symlink(&looped, &looped).unwrap();
    let dangling = dir.path().join("gone.mcap");
    std::os::unix::fs::symlink(dir.path().join("moved.mcap"), &dangling).unwrap();
    let error = |p: &std::path::Path| datasets::io::recording::Recording::open(p).err().unwrap().to_string();
    let m = error(&looped);
    assert!(m.contains("loop.bag") && m.contains("a loop of symbolic links"), "{m}");
    let m = error(&dangling);
    assert!(m.contains("gone.mcap") && m.contains("moved.mcap, which does not exist"), "{m}");
    let m = error(&dir.path().join("never.bag"));
    assert!(m.contains("no such file or folder"), "{m}");
}
