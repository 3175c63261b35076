//! `--mode auto` ends with the pipeline that fits (issue 22): an organic
//! shape remeshed so that most of its edges are flat and a few sharp — what
//! the share rule of `mechanical::choose_mode` reads as a CAD part — must
//! not come back far above the error the organic pipeline gives.
//!
//! The shape: spot (`data/spot.ply`, a 6k-triangle cow) with every triangle
//! split 1 → 4 at its edge midpoints. The surface is the same; the three
//! new edges inside each old triangle are exactly flat, so half the edges
//! are flat, and spot's creased-looking edges (3.2 % above 30°) stay sharp.

use std::path::Path;

use subdfit::convert::{convert_in_memory, ConvertOptions, Mode};
use subdfit::mesh::TriMesh;

fn split_1_to_4(m: &TriMesh) -> TriMesh {
    let mut positions = m.positions.clone();
    let mut mid = std::collections::HashMap::new();
    let mut midpoint = |a: u32, b: u32, positions: &mut Vec<subdfit::DVec3>| {
        *mid.entry((a.min(b), a.max(b))).or_insert_with(|| {
            positions.push((positions[a as usize] + positions[b as usize]) * 0.5);
            (positions.len() - 1) as u32
        })
    };
    let mut triangles = Vec::with_capacity(4 * m.triangles.len());
    for &[a, b, c] in &m.triangles {
        let ab = midpoint(a, b, &mut positions);
        let bc = midpoint(b, c, &mut positions);
        let ca = midpoint(c, a, &mut positions);
        triangles.extend([[a, ab, ca], [ab, b, bc], [ca, bc, c], [ab, bc, ca]]);
    }
    TriMesh {
        positions,
        triangles,
    }
}

#[test]
fn auto_mode_keeps_a_result_near_the_best_of_both_pipelines() {
    let spot = subdfit::io::read_mesh(&Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot.ply"))
        .unwrap();
    let fine = split_1_to_4(&spot.mesh);
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("spot_split.ply");
    subdfit::io::write_ply(&path, &fine.positions, &fine.triangles, &[], None).unwrap();
    let input = subdfit::io::read_mesh(&path).unwrap();

    let choice = subdfit::mechanical::choose_mode(&input.mesh);
    assert_eq!(
        choice.mode, "mechanical",
        "the test shape must look mechanical to the share rule: {}",
        choice.reason
    );
    let run = |mode: Mode| {
        convert_in_memory(
            &input,
            &ConvertOptions::default().with_mode(mode),
            subdfit::convert::HostRecord::default(),
            &mut |_, _| true,
        )
        .unwrap()
        .report
    };
    let auto = run(Mode::Auto);
    let organic = run(Mode::Organic);
    let rms = |r: &subdfit::convert::Report| r.accuracy.limit.rms_permille;
    let options = serde_json::to_value(&auto.options).unwrap();
    let second = &options["mode"]["second_opinion"];
    eprintln!(
        "auto: RMS L {:.3}‰, {} faces, targets met {}; organic alone {:.3}‰, {} faces; second opinion {second}",
        rms(&auto),
        auto.control.faces,
        auto.targets_met,
        rms(&organic),
        organic.control.faces
    );
    // Mechanical on this shape either misses its own per-face target, and
    // then auto must have compared it with the organic result and said
    // so, or (since mechanical mode enriches each region until it meets
    // the target, issue 38) meets it, and then it needs no second opinion
    // but must still be at least as close to M as the organic result.
    if !second.is_object() {
        assert!(
            auto.targets_met && auto.projectability.unprojectable_area_percent <= 1.0,
            "a mechanical result that missed its target kept without a second opinion: {}",
            options["mode"]
        );
        assert!(
            rms(&auto) <= rms(&organic),
            "auto kept RMS {:.3}‰, organic alone {:.3}‰",
            rms(&auto),
            rms(&organic)
        );
        return;
    }
    // The kept result is the one `organic_wins` picks with the faces
    // weighed (conciseness is a goal of both papers): RMS × faces, when
    // the organic result met its own target. The organic run repeats
    // exactly, so its figures are the ones auto saw.
    let cand = |c: &serde_json::Value| subdfit::convert::Candidate {
        rms_limit_permille: c["rms_limit_permille"].as_f64().unwrap(),
        unprojectable_area_percent: c["unprojectable_area_percent"].as_f64().unwrap(),
        faces: c["faces"].as_u64().unwrap() as usize,
        seconds: c["seconds"].as_f64().unwrap(),
        targets_met: c["targets_met"].as_bool().unwrap(),
    };
    let (m, o) = (cand(&second["mechanical"]), cand(&second["organic"]));
    assert_eq!(
        (o.faces, o.targets_met),
        (organic.control.faces, organic.targets_met)
    );
    let organic_kept = subdfit::convert::auto::organic_wins(&m, &o, true);
    assert_eq!(
        second["kept"],
        if organic_kept {
            "organic"
        } else {
            "mechanical"
        }
    );
    let kept_rms = if organic_kept {
        o.rms_limit_permille
    } else {
        m.rms_limit_permille
    };
    assert!(
        (rms(&auto) - kept_rms).abs() <= 1e-9 * kept_rms,
        "auto kept RMS {:.3}‰, the chosen candidate has {kept_rms:.3}‰",
        rms(&auto)
    );
    // Whichever is kept, it is not both larger and less accurate than the
    // other (the 1534-face mechanical mesh kept over 99 organic patches at
    // a similar error was the case this rule ends).
    let (k, other) = if organic_kept { (&o, &m) } else { (&m, &o) };
    assert!(
        !(k.faces > other.faces && k.rms_limit_permille > other.rms_limit_permille),
        "auto kept {k:?} over {other:?}"
    );
    assert!(
        k.rms_limit_permille * k.faces as f64 <= other.rms_limit_permille * other.faces as f64
            || !o.targets_met,
        "auto kept {k:?} over the more concise {other:?}"
    );
}
