//! STL files as other programs write them, through `machlink plan`: a multi-solid ASCII
//! file plans all of its solids, an open mesh is roughed with one warning line, and a rough
//! that would cut nothing exits non-zero with one sentence (never exit 0 with an empty
//! program).

use crate::common;
use common::cli::{ok, run as machlink, stderr};

use offset_core::mesh::shapes::{cuboid, height_field};
use offset_core::mesh::stl::write_ascii_stl;
use offset_core::mesh::V3;
use std::path::Path;

fn plan_rough(stl: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    let mut args = vec![
        "plan",
        stl.to_str().unwrap(),
        "--op",
        "rough3d",
        "--tool-diameter",
        "6",
        "--stepdown",
        "3",
        "--tolerance",
        "0.05",
        "--post",
        "grbl",
        "-o",
        out.to_str().unwrap(),
    ];
    args.extend_from_slice(extra);
    machlink(&args)
}

/// The X extents of the program's cutting moves (G1 lines), read back from the file.
fn cut_x_extent(nc: &Path) -> (f64, f64) {
    let tp = machlink_protocols::gcode_read::read(&std::fs::read_to_string(nc).unwrap()).unwrap();
    let mut lo = f64::INFINITY;
    let mut hi = f64::NEG_INFINITY;
    tp.walk(Default::default(), |_, mv, to| {
        if let offset_core::toolpath::Move::Linear { .. } = mv {
            lo = lo.min(to.x);
            hi = hi.max(to.x);
        }
    });
    (lo, hi)
}

#[test]
fn a_multi_solid_ascii_stl_is_roughed_round_every_solid() {
    let dir = tempfile::tempdir().unwrap();
    // the first solid is a block the stock equals; the second stands 40 mm to its right
    let mut text =
        write_ascii_stl(&cuboid(V3::ZERO, V3::new(20.0, 20.0, 10.0))).replace("machlink", "box0");
    text.push_str(
        &write_ascii_stl(&cuboid(V3::new(60.0, 0.0, 0.0), V3::new(80.0, 20.0, 6.0)))
            .replace("machlink", "box1"),
    );
    let stl = dir.path().join("scene.stl");
    std::fs::write(&stl, text).unwrap();
    let out = dir.path().join("scene.nc");
    let o = plan_rough(&stl, &out, &[]);
    ok(&o, "plan rough3d of a two-solid ASCII STL");
    // the gap between the solids is cleared, up to beside the second one
    let (lo, hi) = cut_x_extent(&out);
    assert!(lo < 25.0 && hi > 80.0, "cuts span X {lo}..{hi}");
}

#[test]
fn a_rough_whose_stock_is_the_part_exits_non_zero_in_one_sentence() {
    let dir = tempfile::tempdir().unwrap();
    let stl = dir.path().join("box.stl");
    std::fs::write(
        &stl,
        write_ascii_stl(&cuboid(V3::ZERO, V3::new(20.0, 10.0, 5.0))),
    )
    .unwrap();
    let out = dir.path().join("box.nc");
    let o = plan_rough(&stl, &out, &[]);
    assert!(!o.status.success(), "an empty rough exited 0");
    let e = stderr(&o);
    assert!(
        e.contains("box.stl: nothing to rough: the stock is the part's own")
            && e.trim().lines().count() == 1,
        "{e}"
    );
    assert!(!out.exists(), "an empty program was written");
    // with a stock margin it is roughed
    ok(
        &plan_rough(&stl, &out, &["--stock-margin", "3"]),
        "rough3d with a margin",
    );
}

#[test]
fn an_open_sheet_is_roughed_with_one_warning_line() {
    let dir = tempfile::tempdir().unwrap();
    let m = height_field((0.0, 30.0), (0.0, 20.0), 15, 10, |x, y| {
        2.0 + (x / 6.0).sin() + (y / 5.0).cos()
    });
    let stl = dir.path().join("sheet.stl");
    std::fs::write(&stl, offset_core::mesh::write_stl(&m)).unwrap();
    let out = dir.path().join("sheet.nc");
    let o = plan_rough(&stl, &out, &["--stock-margin", "2"]);
    ok(&o, "plan rough3d of an open sheet");
    let e = stderr(&o);
    let warned: Vec<&str> = e.lines().filter(|l| l.contains("is open:")).collect();
    assert_eq!(warned.len(), 1, "{e}");
    assert!(
        warned[0].contains("boundary edges") && warned[0].contains("upper envelope"),
        "{e}"
    );
}
