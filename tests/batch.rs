//! `subdfit batch`: one folder per asset with `subdfit convert`'s bytes,
//! failures reported without stopping the rest, the summary files, and a
//! rerun that skips finished assets (and only those) in well under a second.

use std::path::Path;
use std::process::{Command, Output};
use std::time::Instant;

fn subdfit(args: &[&str], cwd: &Path) -> Output {
    Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .args(args)
        .current_dir(cwd)
        .output()
        .expect("run subdfit")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

/// report.json without its timings and memory peaks (run to run).
fn stable_report(path: &Path) -> String {
    let text = std::fs::read_to_string(path).unwrap();
    text.lines()
        .filter(|l| !(l.contains("seconds") || l.contains("peak_memory")))
        .collect::<Vec<_>>()
        .join("\n")
}

#[test]
fn batch_converts_reports_and_resumes() {
    let tmp = tempfile::tempdir().unwrap();
    let root = tmp.path();
    let lib = root.join("lib");
    std::fs::create_dir_all(&lib).unwrap();
    let spot = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot.ply");
    std::fs::copy(&spot, lib.join("spot.ply")).unwrap();
    std::fs::write(
        lib.join("nan.off"),
        "OFF\n3 1 0\n0 0 0\n1 0 0\nnan 1 0\n3 0 1 2\n",
    )
    .unwrap();
    let bytes = std::fs::read(&spot).unwrap();
    std::fs::write(lib.join("cut.ply"), &bytes[..bytes.len() / 2]).unwrap();
    // A manifest naming one of them again and a missing file.
    std::fs::write(root.join("list.txt"), "lib/spot.ply\nlib/gone.obj\n").unwrap();

    let out = subdfit(
        &["batch", "lib", "list.txt", "-o", "out", "--jobs", "2"],
        root,
    );
    let (stdout, stderr) = (text(&out.stdout), text(&out.stderr));
    assert_eq!(out.status.code(), Some(2), "{stdout}\n{stderr}");
    assert!(
        stdout.contains("4 assets: 1 converted, 0 skipped (unchanged), 3 failed"),
        "{stdout}"
    );
    for (name, what) in [
        (
            "nan",
            "lib/nan.off: vertex 2 (line 5): non-finite coordinate",
        ),
        ("cut", "lib/cut.ply: face 1567 (byte 55749): file truncated"),
        ("gone", "lib/gone.obj"),
    ] {
        assert!(
            stdout.contains(&format!("failed: {name}: input mesh: {what}")),
            "{name}: {stdout}"
        );
        assert!(!root.join("out").join(name).exists(), "{name}");
    }

    // The asset's folder is what `subdfit convert` writes for that path.
    let cli = subdfit(&["convert", "lib/spot.ply", "-o", "cli", "--quiet"], root);
    assert!(cli.status.success(), "{}", text(&cli.stderr));
    for f in [
        "control.obj",
        "control.usda",
        "limit.ply",
        "displaced.ply",
        "displacement.exr",
        "displacement_vector.exr",
        "fitmap.ply",
    ] {
        let a = std::fs::read(root.join("out/spot").join(f)).unwrap();
        assert!(a == std::fs::read(root.join("cli").join(f)).unwrap(), "{f}");
    }
    assert_eq!(
        stable_report(&root.join("out/spot/report.json")),
        stable_report(&root.join("cli/report.json"))
    );

    // The summaries: a row per asset, figures for the good one, errors.
    let csv = std::fs::read_to_string(root.join("out/batch.csv")).unwrap();
    let rows: Vec<&str> = csv.lines().collect();
    assert_eq!(rows.len(), 5, "{csv}");
    assert!(rows[0].starts_with("asset,status,mode,input,output,seconds,error,input.faces"));
    assert!(rows[1].starts_with("cut,failed,"), "{csv}");
    let spot_row = rows.iter().find(|r| r.starts_with("spot,")).unwrap();
    assert!(spot_row.starts_with("spot,converted,organic,lib/spot.ply,out/spot,"));
    let json: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(root.join("out/batch.json")).unwrap())
            .unwrap();
    let spot_json = json
        .as_array()
        .unwrap()
        .iter()
        .find(|a| a["name"] == "spot")
        .unwrap();
    assert_eq!(spot_json["figures"]["input.faces"], 5856.0);
    assert!(
        spot_json["figures"]["accuracy.limit.rms_permille"]
            .as_f64()
            .unwrap()
            > 0.0
    );

    // Rerun: the converted asset is skipped, fast; the failures are retried.
    let t = Instant::now();
    let again = subdfit(&["batch", "lib", "list.txt", "-o", "out"], root);
    let secs = t.elapsed().as_secs_f64();
    let stdout = text(&again.stdout);
    assert!(
        stdout.contains("4 assets: 0 converted, 1 skipped (unchanged), 3 failed"),
        "{stdout}"
    );
    assert!(secs < 1.0, "second run took {secs} s");
    let report_before = std::fs::read(root.join("out/spot/report.json")).unwrap();
    assert_eq!(
        report_before,
        std::fs::read(root.join("out/spot/report.json")).unwrap()
    );

    // Changed content, same name: converted again.
    std::fs::copy(root.join("lib/nan.off"), root.join("lib/spot.ply")).unwrap();
    let changed = subdfit(&["batch", "lib/spot.ply", "-o", "out", "--quiet"], root);
    assert_eq!(changed.status.code(), Some(2));
    let json = std::fs::read_to_string(root.join("out/batch.json")).unwrap();
    assert!(json.contains("\"status\": \"failed\""), "{json}");
}
