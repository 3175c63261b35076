//! Issue 38's regression set: procedural CAD parts
//! (`subdfit::fixtures::cad::parts`: plates with grids of holes, bosses,
//! tubes, ribs, countersunk holes, sharp and filleted rims, genus 5 to 9)
//! converted by
//! `--mode mechanical` at the defaults. Each must meet `--max-error` on
//! every control face (`targets_met`, measured by `report.json` on the
//! final surface, S→M), keep every control vertex at valence 20 or less,
//! and stay within 3‰ RMS (the bar for CAD parts).

use std::path::Path;
use std::process::Command;

fn convert(input: &Path, out: &Path) -> serde_json::Value {
    let o = Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .args(["convert", "--mode", "mechanical", "--quiet", "-o"])
        .arg(out)
        .arg(input)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{}: {err}", input.display());
    serde_json::from_str(&std::fs::read_to_string(out.join("report.json")).unwrap()).unwrap()
}

/// Converts each part and returns what failed: a face over `--max-error`
/// (`targets_met`), a control vertex above valence 20, an RMS above 3‰,
/// or (when `max_secs` is given) a conversion slower than that.
fn check(
    parts: Vec<(&'static str, subdfit::fixtures::cad::Plate)>,
    max_secs: Option<f64>,
) -> Vec<String> {
    let dir = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    for (name, plate) in parts {
        let m = plate.mesh();
        let input = dir.path().join(format!("{name}.ply"));
        subdfit::io::write_ply(&input, &m.positions, &m.triangles, &[], None).unwrap();
        let t = std::time::Instant::now();
        let r = convert(&input, &dir.path().join(name));
        let secs = t.elapsed().as_secs_f64();
        let c = &r["control"];
        let max_valence = c["valence_histogram"]
            .as_object()
            .unwrap()
            .keys()
            .map(|k| k.parse::<usize>().unwrap())
            .max()
            .unwrap();
        let s2m = &r["accuracy"]["limit"]["surface_to_mesh"];
        let rms = s2m["rms_permille"].as_f64().unwrap();
        let met = r["targets_met"].as_bool().unwrap();
        // The verdict must describe the control mesh written: the figures
        // it is taken from (`stats.output`) are of a mesh with the written
        // face count, and agree with it. (It was once the last enrichment
        // round's, measured before each region's best state was put back
        // and the final geometry pass: 547 faces measured, 570 written.)
        let out = &r["options"]["mechanical"]["stats"]["output"];
        assert_eq!(
            out["faces"], c["faces"],
            "{name}: verdict measured on another mesh"
        );
        assert_eq!(
            out["vertices"], c["vertices"],
            "{name}: verdict measured on another mesh"
        );
        assert_eq!(
            met,
            out["faces_over_limit"].as_u64() == Some(0),
            "{name}: targets_met disagrees with the written mesh's faces over the limit"
        );
        println!(
            "{name}: {} triangles -> {} faces, RMS {rms:.3}‰ max {:.2}‰, max valence {max_valence}, targets met {met}, {secs:.1} s",
            m.triangles.len(),
            c["faces"],
            s2m["max_permille"].as_f64().unwrap()
        );
        let slow = max_secs.is_some_and(|s| secs > s);
        if !met || max_valence > 20 || rms > 3.0 || slow {
            failures.push(format!(
                "{name}: targets met {met}, max valence {max_valence}, RMS {rms:.3}‰, {secs:.1} s ({})",
                r["targets"][0]["outcome"]
            ));
        }
    }
    failures
}

#[test]
fn cad_parts_meet_max_error_with_bounded_valence() {
    let failures = check(subdfit::fixtures::cad::parts(), None);
    assert!(failures.is_empty(), "{failures:#?}");
}

/// The exported-CAD-sized parts (35k–48k triangles, genus 6 to 20) of
/// `heavy_parts`, with the 15 s per part: too slow for the suite,
/// run by `bench/mechanical.sh` or by hand with
/// `cargo test --release --test mechanical_parts -- --ignored --nocapture`
/// (the time bar holds on an idle 2-core machine; under load from other
/// builds, read the seconds printed).
#[test]
#[ignore = "heavy CAD parts (5-15 s each in release): cargo test --release --test mechanical_parts -- --ignored"]
fn heavy_cad_parts_meet_max_error_within_15_s() {
    let parts = subdfit::fixtures::cad::heavy_parts();
    let failures = check(parts, Some(15.0));
    assert!(failures.is_empty(), "{failures:#?}");
}
