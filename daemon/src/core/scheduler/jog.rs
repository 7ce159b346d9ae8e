//! A jog checked as every job is: its target inside the machine's work area, its feed at
//! most `max_feed`, and no move in X or Y while the tool stands below the stock top (work
//! Z 0, where a cancel may have left it in the part) unless the operator confirms.

use crate::core::machine::MachineConfig;
use machlink_protocols::Operation;

/// Checks `op` (a jog from `at`, the tool's work position when the machine could say it)
/// for machine `m`; one sentence naming the axis and the limit when refused.
pub(super) fn check(
    m: &MachineConfig,
    op: &Operation,
    at: Option<[f64; 3]>,
    confirmed: bool,
) -> Result<(), String> {
    let Operation::Jog { x, y, z, feed } = op else {
        return Ok(());
    };
    let name = &m.name;
    if let Some(max) = m.max_feed {
        if *feed > max + 1e-9 {
            return Err(format!(
                "the jog's feed {feed} mm/min is above machine `{name}`'s limit of {max} mm/min (max_feed)"
            ));
        }
    }
    let Some(at) = at else {
        if m.work_area.is_some() {
            return Err(format!(
                "machine `{name}` cannot say where it stands, so a jog cannot be checked against its work area"
            ));
        }
        return Ok(());
    };
    let by = [*x, *y, *z];
    if let Some(w) = &m.work_area {
        for (k, axis) in ["X", "Y", "Z"].iter().enumerate() {
            let Some(d) = by[k] else { continue };
            let to = at[k] + d;
            if to < w.min[k] - 1e-9 || to > w.max[k] + 1e-9 {
                return Err(format!(
                    "the jog goes to {axis} {to:.3} (from {axis} {:.3} by {d}), outside machine `{name}`'s work area ({axis} {} to {}); nothing moved",
                    at[k], w.min[k], w.max[k]
                ));
            }
        }
    }
    let sideways = x.is_some_and(|v| v != 0.0) || y.is_some_and(|v| v != 0.0);
    if sideways && at[2] < -1e-6 && !confirmed {
        return Err(format!(
            "the tool stands at Z {:.3}, below the stock top (Z 0): a jog in X or Y would drag it through the part; jog Z up first (`machlink jog {name} --z {:.1} --feed 300`), or give --yes; nothing moved",
            at[2],
            (-at[2]) + 5.0
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::core::machine::WorkArea;

    fn router() -> MachineConfig {
        let registry = crate::core::registry::standard();
        let mut m = MachineConfig::new(
            &registry,
            "router",
            "grbl",
            serde_json::json!({ "port": "/dev/null" }),
        )
        .unwrap();
        m.work_area = Some(WorkArea {
            min: [0.0, 0.0, -50.0],
            max: [300.0, 200.0, 50.0],
        });
        m.max_feed = Some(3000.0);
        m
    }

    fn jog(x: Option<f64>, y: Option<f64>, z: Option<f64>, feed: f64) -> Operation {
        Operation::Jog { x, y, z, feed }
    }

    #[test]
    fn a_jog_past_the_work_area_is_refused_naming_the_axis_and_limit() {
        let e = check(
            &router(),
            &jog(Some(1000.0), None, None, 500.0),
            Some([91.5, 0.0, 0.0]),
            false,
        )
        .unwrap_err();
        assert!(e.contains("X 1091.500") && e.contains("X 0 to 300"), "{e}");
        assert!(check(
            &router(),
            &jog(Some(100.0), None, None, 500.0),
            Some([91.5, 0.0, 0.0]),
            false
        )
        .is_ok());
    }

    #[test]
    fn a_jog_faster_than_max_feed_is_refused() {
        let e = check(
            &router(),
            &jog(None, None, Some(1.0), 9000.0),
            Some([0.0; 3]),
            false,
        )
        .unwrap_err();
        assert!(e.contains("9000") && e.contains("3000"), "{e}");
    }

    #[test]
    fn an_xy_jog_below_the_stock_top_needs_the_operators_yes() {
        let below = Some([10.0, 10.0, -2.0]);
        let e = check(&router(), &jog(Some(5.0), None, None, 500.0), below, false).unwrap_err();
        assert!(
            e.contains("below the stock top") && e.contains("--yes"),
            "{e}"
        );
        assert!(check(&router(), &jog(Some(5.0), None, None, 500.0), below, true).is_ok());
        assert!(check(&router(), &jog(None, None, Some(5.0), 500.0), below, false).is_ok());
    }
}
