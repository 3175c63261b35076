//! USD and `--displacement-reconstruction bspline` (docs/handoff.md, issue
//! 37 item 2): `UsdUVTexture` has no cubic filter, so the USD of a B-spline
//! conversion binds `displacement_bilinear.exr`, the spline evaluated at
//! every sample. Checked here on the written files alone: at every texel of
//! every tile (found from `control.obj`'s UVs, texel centres at the patch
//! corners), the bilinear map holds the cubic B-spline of the coefficient
//! map at that knot, `Σ (1, 4, 1)ᵢ (1, 4, 1)ⱼ c / 36` over the 3 × 3 texels
//! around it (the gutter's linear phantom included at tile borders), to
//! f32 round-off. A default conversion writes no such map and binds
//! `displacement.exr` as before.

use std::path::Path;
use std::process::Command;

use subdfit::displace::read_exr;

fn convert(out: &Path, extra: &[&str]) {
    let spot = Path::new(env!("CARGO_MANIFEST_DIR")).join("data/spot.ply");
    let o = Command::new(env!("CARGO_BIN_EXE_subdfit"))
        .arg("convert")
        .arg(&spot)
        .arg("-o")
        .arg(out)
        .args(["--quiet", "--tessellation", "4"])
        .args(extra)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// Per quad of `control.obj`, the texel rectangle `(x0, y0, x1, y1)` of its
/// tile in a `w × h` image (UV (0, 0) at the bottom left, texel centres at
/// half-integers).
fn tiles(obj: &str, w: usize, h: usize) -> Vec<[usize; 4]> {
    let mut uvs = Vec::new();
    let mut out = Vec::new();
    for line in obj.lines() {
        let t: Vec<&str> = line.split_whitespace().collect();
        match t.first() {
            Some(&"vt") => {
                let (u, v): (f64, f64) = (t[1].parse().unwrap(), t[2].parse().unwrap());
                let x = u * w as f64 - 0.5;
                let y = (1.0 - v) * h as f64 - 0.5;
                assert!((x - x.round()).abs() < 1e-6 && (y - y.round()).abs() < 1e-6);
                uvs.push((x.round() as usize, y.round() as usize));
            }
            Some(&"f") => {
                let c: Vec<(usize, usize)> = t[1..]
                    .iter()
                    .map(|c| uvs[c.split('/').nth(1).unwrap().parse::<usize>().unwrap() - 1])
                    .collect();
                let xs = c.iter().map(|p| p.0);
                let ys = c.iter().map(|p| p.1);
                out.push([
                    xs.clone().min().unwrap(),
                    ys.clone().min().unwrap(),
                    xs.max().unwrap(),
                    ys.max().unwrap(),
                ]);
            }
            _ => {}
        }
    }
    out
}

#[test]
fn usd_of_a_bspline_conversion_binds_the_splines_samples() {
    let tmp = tempfile::tempdir().unwrap();
    let (bs, bl) = (tmp.path().join("bspline"), tmp.path().join("bilinear"));
    convert(&bs, &["--displacement-reconstruction", "bspline"]);
    convert(&bl, &[]);
    let usda = std::fs::read_to_string(bs.join("control.usda")).unwrap();
    assert!(usda.contains("@./displacement_bilinear.exr@"), "{usda}");
    let usda = std::fs::read_to_string(bl.join("control.usda")).unwrap();
    assert!(usda.contains("@./displacement.exr@"), "{usda}");
    assert!(!bl.join("displacement_bilinear.exr").exists());
    assert!(bs.join("displacement_bilinear_vector.exr").is_file());

    let (w, h, coef) = read_exr(&bs.join("displacement.exr")).unwrap();
    let (w2, h2, samples) = read_exr(&bs.join("displacement_bilinear.exr")).unwrap();
    assert_eq!((w, h), (w2, h2));
    let obj = std::fs::read_to_string(bs.join("control.obj")).unwrap();
    let rects = tiles(&obj, w, h);
    assert!(rects.len() > 50, "{} patches", rects.len());
    let c = |x: usize, y: usize| coef[y * w + x] as f64;
    let scale = coef.iter().fold(0.0f64, |m, &v| m.max(v.abs() as f64));
    let (mut texels, mut worst) = (0usize, 0.0f64);
    for [x0, y0, x1, y1] in rects {
        assert!(x0 >= 1 && y0 >= 1 && x1 + 1 < w && y1 + 1 < h);
        for y in y0..=y1 {
            for x in x0..=x1 {
                let k = [1.0, 4.0, 1.0];
                let mut spline = 0.0;
                for (dy, ky) in k.iter().enumerate() {
                    for (dx, kx) in k.iter().enumerate() {
                        spline += kx * ky * c(x + dx - 1, y + dy - 1);
                    }
                }
                spline /= 36.0;
                worst = worst.max((samples[y * w + x] as f64 - spline).abs());
                texels += 1;
            }
        }
    }
    // f32 texels: the coefficients and the samples are each rounded once
    // (relative 6e-8), and the sum of nine of them once more in f64.
    assert!(
        worst <= 1e-6 * scale,
        "bilinear map off the spline by {worst:e} (largest coefficient {scale:e}) over {texels} texels"
    );
}
