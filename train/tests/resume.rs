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
    // A state or settings file edited into what this run cannot have written is refused, naming it.
    let folder = train::RunFolder::new(parts.path());
    let state_path = parts.path().join("resume/state.json");
    let config_path = parts.path().join("train_config.json");
    let (state, config) =
        (std::fs::read_to_string(&state_path).unwrap(), std::fs::read_to_string(&config_path).unwrap());
    let edit = |path: &std::path::Path, text: &str, key: &str, value: u64| {
        let mut json: serde_json::Value = serde_json::from_str(text).unwrap();
        json[key] = value.into();
        std::fs::write(path, json.to_string()).unwrap();
    };
    for (done, why) in [(99, "says 99 epochs are done of the 3"), (0, "says 0 epochs are done of the 3")] {
        edit(&state_path, &state, "epochs_done", done);
        let error = folder.read_for_resume().unwrap_err().to_string();
        assert!(error.contains("state.json") && error.contains(why), "{error}");
    }
    std::fs::write(&state_path, &state).unwrap();
    edit(&config_path, &config, "epochs", 1_000_000_000);
    let error = format!("{:#}", anyhow::Error::from(folder.read_for_resume().unwrap_err()));
    assert!(error.contains("train_config.json") && error.contains("1000000000 outside 1..=10000"), "{error}");
    std::fs::write(&config_path, &config).unwrap();
    // Killed between the two renames that replace the resume state, with a
    // temporary folder and file left behind.
    let run = parts.path();
    std::fs::rename(run.join("resume"), run.join(".old-resume")).unwrap();
    std::fs::create_dir(run.join(".tmp-dir-killed")).unwrap();
    std::fs::write(run.join(".tmp-killed.csv"), "half a line").unwrap();
    train::train(None, parts.path(), false).unwrap();
    let leftovers: Vec<_> = std::fs::read_dir(run)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with(".tmp-") || n.starts_with(".old-"))
        .collect();
    assert!(leftovers.is_empty(), "{leftovers:?}");
    let (a, b) = (train_losses(whole.path()), train_losses(parts.path()));
    assert_eq!(a.len(), b.len());
    for (k, (x, y)) in a.iter().zip(&b).enumerate() {
        assert_eq!(x, y, "iteration {k}: uninterrupted vs resumed (the log keeps 6 decimals)");
    }
}

#[test]
fn resume_refuses_flags_that_would_change_the_run() {
    let dir = tempfile::tempdir().unwrap();
    let run = dir.path().to_str().unwrap();
    for flag in
        [&["--epochs", "5"][..], &["--lr", "0.1"], &["--batch-size", "2"], &["--seed", "3"], &["--adaptive-canny"]]
    {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_train"))
            .args(["--resume", run])
            .args(flag)
            .output()
            .unwrap();
        let message = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success() && message.contains("--resume") && message.contains(flag[0]), "{message}");
    }
}

#[test]
fn bad_flags_and_unusable_folders_get_messages_that_name_them() {
    let dir = tempfile::tempdir().unwrap();
    let train = |args: &[&str]| {
        let out = std::process::Command::new(env!("CARGO_BIN_EXE_train"))
            .args(args)
            .env("RUST_BACKTRACE", "1")
            .output()
            .unwrap();
        assert!(!out.status.success());
        String::from_utf8_lossy(&out.stderr).into_owned()
    };
    let data = dir.path().to_str().unwrap();
    let base = ["--backbone", "alexnet", "--data", data];
    // A negative count is a bad value of its flag, not an unknown argument.
    for (flag, value) in [("--epochs", "-1"), ("--batch-size", "0"), ("--lr", "-0.5"), ("--lr", "NaN")] {
        let out = dir.path().join("run");
        let message = train(&[&base[..], &["--out", out.to_str().unwrap(), flag, value]].concat());
        assert!(
            message.contains(flag) && message.contains(value) && !message.contains("unexpected argument"),
            "{message}"
        );
    }
    // Another command's folder is not written into.
    let other = dir.path().join("localize-run");
    std::fs::create_dir(&other).unwrap();
    std::fs::write(other.join("metrics.json"), "{\"theirs\": 1}").unwrap();
    let message = train(&[&base[..], &["--out", other.to_str().unwrap()]].concat());
    assert!(message.contains("localize-run") && message.contains("not empty (it holds metrics.json"), "{message}");
    assert_eq!(std::fs::read_to_string(other.join("metrics.json")).unwrap(), "{\"theirs\": 1}");
    // A count that would never end is refused before any work.
    let out = dir.path().join("run");
    let message = train(&[&base[..], &["--out", out.to_str().unwrap(), "--epochs", "1000000000"]].concat());
    assert!(message.contains("epochs: 1000000000 outside 1..=10000"), "{message}");
    assert!(!out.exists(), "nothing written");
    // An output that is a file: the error names it (not a bare "File exists"),
    // and an ordinary error prints no backtrace even with RUST_BACKTRACE set.
    let file = dir.path().join("a-file");
    std::fs::write(&file, "x").unwrap();
    let message = train(&[&base[..], &["--out", file.to_str().unwrap(), "--epochs", "1"]].concat());
    assert!(message.contains("a-file"), "{message}");
    assert!(!message.to_lowercase().contains("backtrace"), "{message}");
}

#[test]
fn a_relative_data_folder_is_kept_absolute_so_a_resume_from_elsewhere_finds_it() {
    let data = common::tiny_data();
    let out = tempfile::tempdir().unwrap();
    let run = out.path().join("run");
    let status = std::process::Command::new(env!("CARGO_BIN_EXE_train"))
        .current_dir(data.parent().unwrap())
        .args(["--backbone", "alexnet", "--data", "detection", "--width", "0.125", "--epochs", "1"])
        .args(["--batch-size", "2", "--out", run.to_str().unwrap()])
        .env("CI", "true")
        .output()
        .unwrap();
    assert!(status.status.success(), "{}", String::from_utf8_lossy(&status.stderr));
    let settings: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("train_config.json")).unwrap()).unwrap();
    let kept = std::path::PathBuf::from(settings["data"].as_str().unwrap());
    assert!(kept.is_absolute() && kept == *data, "{kept:?} vs {data:?}");
}

#[test]
fn a_config_file_lies_over_the_defaults_and_flags_over_it() {
    let data = common::tiny_data();
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("settings.json");
    // A subset of a run's train_config.json: epochs the flag replaces, the rest kept.
    std::fs::write(&file, r#"{"epochs": 5, "seed": 7, "weight_decay": 0.0, "detector": {"hidden": 96}}"#).unwrap();
    let run = dir.path().join("run");
    let train = |args: &[&str]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_train"))
            .args(["--backbone", "alexnet", "--data", data.to_str().unwrap(), "--width", "0.125"])
            .args(args)
            .env("CI", "true")
            .output()
            .unwrap()
    };
    let out = train(&[
        "--config",
        file.to_str().unwrap(),
        "--epochs",
        "1",
        "--batch-size",
        "2",
        "--out",
        run.to_str().unwrap(),
    ]);
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let written: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(run.join("train_config.json")).unwrap()).unwrap();
    assert_eq!((written["epochs"].as_u64(), written["seed"].as_u64()), (Some(1), Some(7)));
    assert_eq!((written["batch_size"].as_u64(), written["weight_decay"].as_f64()), (Some(2), Some(0.0)));
    assert_eq!(written["detector"]["hidden"].as_u64(), Some(96));
    // Alexnet's default peak learning rate, which the file did not name.
    assert_eq!(written["lr"].as_f64(), Some(2e-3));
    // A field the settings do not have, and a detector of another backbone, are named.
    std::fs::write(&file, r#"{"epocs": 5}"#).unwrap();
    let other = dir.path().join("other");
    let message =
        String::from_utf8_lossy(&train(&["--config", file.to_str().unwrap(), "--out", other.to_str().unwrap()]).stderr)
            .into_owned();
    assert!(message.contains("settings.json") && message.contains("unknown field `epocs`"), "{message}");
    std::fs::copy(run.join("train_config.json"), &file).unwrap();
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_train"))
        .args(["--backbone", "vgg16", "--data", data.to_str().unwrap(), "--config", file.to_str().unwrap()])
        .args(["--out", other.to_str().unwrap()])
        .output()
        .unwrap();
    let message = String::from_utf8_lossy(&out.stderr);
    assert!(message.contains("backbone is alexnet, but --backbone is vgg16"), "{message}");
    assert!(!other.exists(), "nothing written");
    // --resume takes its settings from the run: a file is refused beside it.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_train"))
        .args(["--resume", run.to_str().unwrap(), "--config", file.to_str().unwrap()])
        .output()
        .unwrap();
    assert!(!out.status.success() && String::from_utf8_lossy(&out.stderr).contains("--config"));
}
