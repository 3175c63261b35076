//! `report.json`'s keys are a promise to every reader of it (the CLI's
//! `--json`, `report.html`, batch summaries, hosts' scripts): the key sets
//! of an organic and a mechanical conversion must stay those of the golden
//! lists in `tests/data/report_keys/`, taken from `subdfit convert` on the
//! same meshes before the run record was moved into `src/convert/`.
//! A key added or renamed on purpose updates the list in the same commit.
//!
//! Paths are dotted; array elements are `[]`; the keys of
//! `valence_histogram` and `resolution_histogram` (valences and tile
//! resolutions, which depend on the mesh) are `*`.

use std::collections::BTreeSet;
use std::path::Path;

use subdfit::convert::{convert_in_memory, BranchRecord, ConvertOptions, Mode, RunOptions};

/// Every node's path in `v` below `prefix`, null and `false` leaves
/// included (as `jq paths` lists them).
fn key_paths(v: &serde_json::Value, prefix: &str, out: &mut BTreeSet<String>) {
    let join = |k: &str| {
        if prefix.is_empty() {
            k.to_string()
        } else {
            format!("{prefix}.{k}")
        }
    };
    match v {
        serde_json::Value::Object(m) => {
            let histogram =
                prefix.ends_with("valence_histogram") || prefix.ends_with("resolution_histogram");
            for (k, child) in m {
                let p = join(if histogram { "*" } else { k });
                out.insert(p.clone());
                key_paths(child, &p, out);
            }
        }
        serde_json::Value::Array(a) => {
            for child in a {
                let p = join("[]");
                out.insert(p.clone());
                key_paths(child, &p, out);
            }
        }
        _ => {}
    }
}

fn check(mesh: &str, mode: Mode, golden: &str) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let path = root.join("data").join(mesh);
    let input = subdfit::io::read_mesh(&path)
        .and_then(|m| m.into_manifold(&path))
        .unwrap();
    // The `run` record the CLI writes.
    let extra = subdfit::convert::HostRecord::convert(path.display().to_string());
    let c = convert_in_memory(
        &input,
        &ConvertOptions::default()
            .with_tolerance(Some(subdfit::analysis::fitmap::DEFAULT_TOLERANCE))
            .with_mode(mode),
        extra,
        &mut |_, _| true,
    )
    .unwrap();
    let mut got = BTreeSet::new();
    key_paths(&serde_json::to_value(&c.report).unwrap(), "", &mut got);
    record_round_trips(&c.report, mode);
    let want: BTreeSet<String> =
        std::fs::read_to_string(root.join("tests/data/report_keys").join(golden))
            .unwrap()
            .lines()
            .map(str::to_string)
            .collect();
    let missing: Vec<_> = want.difference(&got).collect();
    let added: Vec<_> = got.difference(&want).collect();
    assert!(
        missing.is_empty() && added.is_empty(),
        "{mesh} ({mode:?}): report.json keys changed\nmissing: {missing:#?}\nadded: {added:#?}"
    );
}

/// `report.json`'s `options`, as the file holds it, read into the typed
/// record (`RunOptions`) and written again: the same keys and the same
/// values, so a host can read a finished run's record typed.
fn record_round_trips(report: &impl serde::Serialize, mode: Mode) {
    // The bytes report.json gets (report/output.rs writes them so).
    let text = serde_json::to_string_pretty(report).unwrap();
    let file: serde_json::Value = serde_json::from_str(&text).unwrap();
    let options = &file["options"];
    let record: RunOptions = serde_json::from_value(options.clone()).unwrap_or_else(|e| {
        // The untagged enum hides which part failed: the branch's record
        // says it.
        let branch = options.get("run").filter(|r| r.get("mode").is_some());
        let why = serde_json::from_value::<BranchRecord>(branch.unwrap_or(options).clone())
            .err()
            .map_or_else(String::new, |e| e.to_string());
        panic!("{mode:?}: options do not read back: {e} ({why})")
    });
    let again = serde_json::to_value(&record).unwrap();
    let (mut a, mut b) = (BTreeSet::new(), BTreeSet::new());
    key_paths(options, "", &mut a);
    key_paths(&again, "", &mut b);
    assert_eq!(a, b, "{mode:?}: the record's keys changed on the way back");
    assert_eq!(&again, options, "{mode:?}: the record's values changed");
    // Typed readers see what the file says.
    let kept = match mode {
        Mode::Mechanical => "mechanical",
        _ => "organic",
    };
    assert_eq!(record.mode(), Some(kept));
    assert_eq!(record.host().command, "convert");
    assert!(
        record.host().mesh.ends_with(".ply"),
        "{}",
        record.host().mesh
    );
    assert_eq!(
        record.mechanical_initial_faces().is_some(),
        mode == Mode::Mechanical
    );
}

#[test]
fn organic_report_keeps_its_keys() {
    check("spot.ply", Mode::Organic, "organic_spot.txt");
}

#[test]
fn mechanical_report_keeps_its_keys() {
    check("fandisk.ply", Mode::Mechanical, "mechanical_fandisk.txt");
}

#[test]
fn key_paths_name_nested_keys_arrays_and_histograms() {
    let v = serde_json::json!({
        "a": { "b": [ { "c": 1 } ], "valence_histogram": { "3": 2, "5": 1 } },
        "e": []
    });
    let mut got = BTreeSet::new();
    key_paths(&v, "", &mut got);
    let want = [
        "a",
        "a.b",
        "a.b.[]",
        "a.b.[].c",
        "a.valence_histogram",
        "a.valence_histogram.*",
        "e",
    ];
    assert_eq!(got, want.iter().map(|s| s.to_string()).collect());
}
