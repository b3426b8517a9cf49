//! A short, bounded fuzz run of every target, as part of the tests: the
//! seeds (generated, the repository's recordings and checkpoint configs, and
//! the real files of `../shared/data` when that folder is there) and a fixed
//! number of seeded mutations of them. Long runs: see fuzz/README.md.

use std::path::PathBuf;

use fuzz::Target;
use fuzz::runner::{Budget, run};

#[global_allocator]
static ALLOCATOR: fuzz::alloc_cap::CappedAllocator = fuzz::alloc_cap::CappedAllocator;

fn seed_dirs() -> Vec<PathBuf> {
    let root = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("..");
    let mut dirs = vec![root.join("datasets/tests/data"), root.join("checkpoints")];
    let shared = root.join("../shared/data");
    if shared.is_dir() {
        dirs.push(shared);
    }
    dirs
}

#[test]
fn every_target_survives_its_seeds_and_their_mutations() {
    let corpus = fuzz::seeds::collect(&seed_dirs());
    let mut report = Vec::new();
    for target in Target::ALL {
        let seeds = corpus.get(target.name()).cloned().unwrap_or_default();
        assert!(!seeds.is_empty(), "target {} has no seeds", target.name());
        // Recordings and SQLite files are slower per case.
        let cases = match target {
            Target::Sqlite3 | Target::Mcap | Target::Ros1Bag => 300,
            _ => 1500,
        };
        match run(target, &seeds, 20261202, Budget::Cases(seeds.len() as u64 + cases), &mut |_| {}) {
            Ok(stats) => report.push(format!("{}: {} cases", target.name(), stats.executions)),
            Err(crash) => panic!(
                "{crash}\nreplay: cargo run -p fuzz -- case --target {} --case {} --seed 20261202 --out case.bin",
                crash.target.name(),
                crash.case
            ),
        }
    }
    println!("{}", report.join("\n"));
}

#[test]
fn the_generated_seeds_are_accepted_by_their_parsers() {
    // A seed the parser refuses would make the fuzzer start outside the
    // format; the project's writers and readers must agree.
    for (target, data) in fuzz::seeds::generated() {
        let accepted = match target {
            Target::Pcd => {
                datasets::io::formats::pcd::read_pcd_bytes("s.pcd".as_ref(), &data, Default::default()).is_ok()
            }
            Target::Ply => {
                datasets::io::formats::ply::read_ply_bytes("s.ply".as_ref(), &data, Default::default()).is_ok()
            }
            Target::Trajectory => {
                datasets::io::formats::trajectory::parse_trajectory("t.txt".as_ref(), &String::from_utf8_lossy(&data))
                    .is_ok()
            }
            Target::Calib => {
                datasets::io::formats::calib::parse_calibration("c.json".as_ref(), &String::from_utf8_lossy(&data))
                    .is_ok()
            }
            Target::Coco => {
                datasets::io::formats::coco::parse_coco("l.json".as_ref(), &String::from_utf8_lossy(&data)).is_ok()
            }
            Target::CheckpointConfig => {
                infer::checkpoint::parse_config("config.json".as_ref(), &String::from_utf8_lossy(&data)).is_ok()
            }
            Target::McapContent => {
                let path = std::path::Path::new("c.mcap");
                let topics = datasets::io::recording::mcap_file::topics(path, &data).unwrap();
                let mut n = 0;
                datasets::io::recording::mcap_file::visit(path, &data, &mut |_, _, _| {
                    n += 1;
                    Ok(())
                })
                .unwrap();
                // The CRCs it was written with are the ones the target would compute.
                topics.len() == n && n > 5 && fuzz::targets::with_mcap_crcs(&data) == data
            }
            Target::Map => {
                let dir = tempfile::tempdir().unwrap();
                let split = data.iter().position(|&b| b == 0).unwrap();
                std::fs::write(dir.path().join("map.json"), &data[..split]).unwrap();
                std::fs::write(dir.path().join("map.ply"), &data[split + 1..]).unwrap();
                localize::map_output::read_map(dir.path()).is_ok()
            }
            Target::Rosbag2Metadata => {
                let dir = std::path::Path::new("bag");
                let read = datasets::io::recording::rosbag2::parse_metadata(
                    dir,
                    &dir.join("metadata.yaml"),
                    &String::from_utf8_lossy(&data),
                );
                // The alias bomb is a seed the reader must refuse.
                data == fuzz::seeds::alias_bomb(9, 10).as_bytes() || read.is_ok()
            }
            _ => true,
        };
        assert!(accepted, "a generated {} seed is refused by its own reader", target.name());
    }
}

#[test]
fn the_alias_bomb_seed_is_refused_before_it_expands() {
    let dir = std::path::Path::new("bag");
    let bomb = fuzz::seeds::alias_bomb(9, 10);
    let error = datasets::io::recording::rosbag2::parse_metadata(dir, &dir.join("metadata.yaml"), &bomb).unwrap_err();
    assert!(error.to_string().contains("metadata.yaml"), "{error}");
}

#[test]
fn a_declared_huge_size_is_an_error_not_an_allocation() {
    // The failure class the fuzzer guards against, written down once.
    let header = b"# .PCD v0.7\nVERSION 0.7\nFIELDS x y z\nSIZE 4 4 4\nTYPE F F F\nCOUNT 1 1 1\nWIDTH 1000000000000\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 1000000000000\nDATA binary\n";
    let e = datasets::io::formats::pcd::read_pcd_bytes("huge.pcd".as_ref(), header, Default::default()).unwrap_err();
    assert!(e.to_string().contains("huge.pcd"), "{e}");
}
