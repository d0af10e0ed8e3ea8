//! Issue 15's reproducers: small inputs that once exhausted memory, printed non-finite numbers
//! with exit 0 or lost output. Each gives a correct answer or exit 2 with a clear message.

use crate::cli::evitrack;
use evitrack::evidence::{
    dempster_all_within, EvidenceError, MassFunction, Subset, WorkLimit, WorkLimits,
};

/// A combine input of `functions`, each a list of (focal set, mass).
fn combine_input(frame: usize, functions: &[Vec<(Vec<usize>, f64)>]) -> String {
    let fs: Vec<serde_json::Value> = functions
        .iter()
        .map(|f| {
            let (focal, mass): (Vec<_>, Vec<_>) = f.iter().cloned().unzip();
            serde_json::json!({ "focal": focal, "mass": mass })
        })
        .collect();
    serde_json::json!({ "frame": frame, "rule": "dempster", "mass_functions": fs }).to_string()
}

/// Rows and columns of a 100 × 100 grid: 10⁴ distinct intersections, of 2 MB each on a frame of
/// 2²⁴ elements (20 GB unbounded).
fn grid_input(frame: usize) -> String {
    let rows = (0..100)
        .map(|i| ((0..100).map(|j| 100 * i + j).collect(), 0.01))
        .collect();
    let columns = (0..100)
        .map(|j| ((0..100).map(|i| 100 * i + j).collect(), 0.01))
        .collect();
    combine_input(frame, &[rows, columns])
}

/// 22 functions "all but element k, or all": the combination has 2^k focal sets after k steps.
fn exponential_input(functions: usize) -> String {
    let all: Vec<usize> = (0..functions).collect();
    let fs: Vec<_> = (0..functions)
        .map(|k| {
            let but_k = all.iter().copied().filter(|&e| e != k).collect();
            vec![(but_k, 0.5), (all.clone(), 0.5)]
        })
        .collect();
    combine_input(functions, &fs)
}

fn refused(args: &[&str], input: &str, names: &str) {
    let out = evitrack(args, input);
    let stderr = String::from_utf8_lossy(&out.stderr);
    assert_eq!(out.status.code(), Some(2), "{args:?}: {stderr}");
    assert!(stderr.contains(names), "{names:?} not in {stderr}");
    assert!(stderr.contains("raise it with"), "{stderr}");
    assert!(out.stdout.is_empty());
}

#[test]
fn combine_stops_at_its_memory_limit_with_exit_2_and_the_flag_that_raises_it() {
    // On 2¹⁶ elements a set takes 8 KiB: the running result reaches 16 MiB at 2048 of its 10⁴
    // sets (the inputs, 800 KiB each, are within).
    let grid = grid_input(1 << 16);
    refused(
        &["combine", "--max-set-mib", "16", "-"],
        &grid,
        "--max-set-mib (now 16)",
    );
    // Raised far enough, the same grid combines: 10⁴ singletons of mass 10⁻⁴.
    let out = evitrack(&["combine", "--max-set-mib", "80", "-"], &grid);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    let mass = json["mass"].as_array().unwrap();
    assert_eq!(mass.len(), 10_000);
    assert!(mass
        .iter()
        .all(|m| (m.as_f64().unwrap() - 1e-4).abs() < 1e-15));
}

#[test]
fn combine_stops_exponential_growth_at_the_focal_set_limit() {
    let input = exponential_input(22);
    refused(
        &["combine", "--max-focal-sets", "1000", "-"],
        &input,
        "--max-focal-sets (now 1000)",
    );
    // 10 functions make 2¹⁰ − 1 = 1023 non-empty sets: within a limit of 1023, not of 1022.
    let small = exponential_input(10);
    let out = evitrack(&["combine", "--max-focal-sets", "1023", "-"], &small);
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let json: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(json["focal"].as_array().map(Vec::len), Some(1023));
    refused(
        &["combine", "--max-focal-sets", "1022", "-"],
        &small,
        "--max-focal-sets",
    );
}

#[test]
fn combine_refuses_an_input_over_the_limits_before_building_it() {
    // 200 focal sets in all: each function is within 150, the input together is not. On 2²⁴
    // elements, 200 MiB each, 400 MiB together: refused before the sets are built.
    let grid = grid_input(1 << 24);
    refused(
        &["combine", "--max-focal-sets", "150", "-"],
        &grid,
        "--max-focal-sets (now 150)",
    );
    refused(
        &["combine", "--max-set-mib", "300", "-"],
        &grid,
        "--max-set-mib (now 300)",
    );
    refused(
        &["combine", "--max-output-elements", "9999", "-"],
        &combine_input(10_000, &[vec![((0..10).collect(), 1.0)]]),
        "--max-output-elements (now 9999)",
    );
}

#[test]
fn the_library_reports_which_limit_a_combination_reached() {
    let n = 12;
    let fs: Vec<MassFunction> = (0..n)
        .map(|k| {
            let but_k = Subset::from_indices(n, (0..n).filter(|&e| e != k)).unwrap();
            MassFunction::new(n, vec![(but_k, 0.5), (Subset::full(n), 0.5)]).unwrap()
        })
        .collect();
    // 2¹² − 1 non-empty sets (the empty one is the conflict 2⁻¹²).
    let reached = |limits: WorkLimits| match dempster_all_within(&fs, &limits) {
        Err(EvidenceError::WorkLimit { limit, max }) => Some((limit, max)),
        Ok(c) => {
            assert_eq!(c.mass.map(|m| m.focal().count()), Some(4095));
            assert!((c.conflict_mass - 2f64.powi(-12)).abs() < 1e-15);
            None
        }
        Err(e) => panic!("{e}"),
    };
    let sets = |focal_sets| WorkLimits {
        focal_sets,
        ..WorkLimits::DEFAULT
    };
    let bytes = |set_bytes| WorkLimits {
        set_bytes,
        ..WorkLimits::DEFAULT
    };
    assert_eq!(reached(sets(4094)), Some((WorkLimit::FocalSets, 4094)));
    assert_eq!(
        reached(bytes(8 * 4094)),
        Some((WorkLimit::SetBytes, 8 * 4094))
    );
    assert_eq!(reached(sets(4095)), None);
    assert_eq!(reached(bytes(8 * 4095)), None);
}
