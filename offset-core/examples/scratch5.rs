use offset_core::io::{read_shape_with, ReadOptions};
use offset_core::ops::{pocket, profile, Cutting, PocketParams, ProfileParams, Stepover};
use offset_core::toolpath::Tool;
use std::time::Instant;
fn main() {
    for f in std::env::args().skip(1) {
        let b = std::fs::read(&f).unwrap();
        let t = Instant::now();
        let r = read_shape_with(&b, &f, &ReadOptions::default());
        println!(
            "{f}: read {:?} in {:.1} ms",
            r.as_ref()
                .map(|(s, w)| (s.paths.len(), s.bounds(), w.len())),
            t.elapsed().as_secs_f64() * 1e3
        );
        let Ok((shape, _)) = r else { continue };
        for (i, reg) in shape.regions().iter().enumerate() {
            let b = reg.bounds();
            println!(
                "  region {i}: {:.0} x {:.0} mm, area {:.0}",
                b.width(),
                b.height(),
                reg.area()
            );
        }
        let cut = Cutting {
            tool: Tool::flat(3.0),
            ..Default::default()
        };
        let t = Instant::now();
        let r = profile(
            &shape,
            &ProfileParams {
                cut: cut.clone(),
                ..Default::default()
            },
        );
        println!(
            "  profile: {:?} in {:.1} ms",
            r.as_ref()
                .map(|t| (t.moves.len(), t.warnings.clone()))
                .map_err(|e| e.to_string()),
            t.elapsed().as_secs_f64() * 1e3
        );
        let t = Instant::now();
        let r = pocket(
            &shape,
            &PocketParams {
                cut,
                stepover: Stepover::Percent(40.0),
            },
        );
        println!(
            "  pocket: {:?} in {:.1} ms",
            r.as_ref()
                .map(|t| (t.moves.len(), t.warnings.clone()))
                .map_err(|e| e.to_string()),
            t.elapsed().as_secs_f64() * 1e3
        );
    }
}
