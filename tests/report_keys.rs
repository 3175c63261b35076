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

use subdfit::convert::{convert_in_memory, ConvertOptions, Mode};

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
