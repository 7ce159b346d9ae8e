//! A job of several operations: which geometry each takes (layers, colours, circle sizes), and their tool paths joined into one with a tool change wherever the tool differs.

use crate::io::dxf::DxfEntity;
use crate::toolpath::{Move, Tool, ToolKind, Toolpath, P3};
use serde::{Deserialize, Serialize};

/// Which geometry an operation of a job takes; every key given must hold (all when none).
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct Take {
    /// DXF layers, or SVG layers and groups (an Inkscape layer's label or a `<g>`'s id), by
    /// name or glob (`HOLE*`, `?-CUT`), case-insensitive; empty: every layer. Also spelt
    /// `layer = "HOLES"` for one.
    #[serde(
        skip_serializing_if = "Vec::is_empty",
        alias = "layer",
        deserialize_with = "one_or_many"
    )]
    pub layers: Vec<String>,
    /// DXF colour numbers (1 red, 2 yellow, 3 green, 4 cyan, 5 blue, 6 magenta, 7 white…);
    /// empty: every colour.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub colors: Vec<i64>,
    /// Only full circles whose diameter lies in `[min, max]`, mm.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub diameter: Option<[f64; 2]>,
}

impl Take {
    /// Whether this selector takes every entity (no key given).
    pub fn is_all(&self) -> bool {
        self.layers.is_empty() && self.colors.is_empty() && self.diameter.is_none()
    }

    /// The layers of `all` this selector's names and globs match (all of them when it
    /// names none).
    pub fn layers_of(&self, all: &[String]) -> Vec<String> {
        all.iter()
            .filter(|l| self.takes_layer(l))
            .cloned()
            .collect()
    }

    pub fn takes_layer(&self, layer: &str) -> bool {
        self.layers.is_empty() || self.layers.iter().any(|g| glob(g, layer))
    }

    pub fn takes_diameter(&self, d: f64) -> bool {
        self.diameter
            .is_none_or(|[lo, hi]| d >= lo - 1e-9 && d <= hi + 1e-9)
    }

    /// Whether the selector takes a DXF entity: its layer and colour, and for a diameter
    /// range, a CIRCLE of that size.
    pub fn takes(&self, e: &DxfEntity) -> bool {
        self.takes_layer(&e.layer)
            && (self.colors.is_empty() || self.colors.contains(&e.color))
            && match self.diameter {
                None => true,
                Some(_) => e.kind == "CIRCLE" && self.takes_diameter(e.diameter),
            }
    }

    /// Problems with the selector, in one sentence.
    pub fn check(&self) -> Result<(), String> {
        if let Some([lo, hi]) = self.diameter {
            if !(lo.is_finite() && hi.is_finite() && lo >= 0.0 && lo <= hi) {
                return Err(format!(
                    "the diameter range [{lo}, {hi}] must be two numbers, 0 ≤ min ≤ max"
                ));
            }
        }
        Ok(())
    }
}

/// A list of names, or one name alone (`layer = "HOLES"`).
fn one_or_many<'de, D: serde::Deserializer<'de>>(d: D) -> Result<Vec<String>, D::Error> {
    #[derive(Deserialize)]
    #[serde(untagged)]
    enum OneOrMany {
        One(String),
        Many(Vec<String>),
    }
    Ok(match OneOrMany::deserialize(d)? {
        OneOrMany::One(s) => vec![s],
        OneOrMany::Many(v) => v,
    })
}

/// Whether `name` matches the glob `pattern` (`*` any run, `?` one character),
/// case-insensitively.
pub fn glob(pattern: &str, name: &str) -> bool {
    let p: Vec<char> = pattern.to_uppercase().chars().collect();
    let n: Vec<char> = name.to_uppercase().chars().collect();
    let (mut pi, mut ni) = (0, 0);
    let (mut star, mut mark) = (None, 0);
    while ni < n.len() {
        if pi < p.len() && (p[pi] == '?' || p[pi] == n[ni]) {
            pi += 1;
            ni += 1;
        } else if pi < p.len() && p[pi] == '*' {
            star = Some(pi);
            mark = ni;
            pi += 1;
        } else if let Some(s) = star {
            pi = s + 1;
            mark += 1;
            ni = mark;
        } else {
            return false;
        }
    }
    p[pi..].iter().all(|&c| c == '*')
}

/// One operation's planned path, with the tool it runs with.
#[derive(Clone, Debug)]
pub struct Step {
    /// The operation's name for the operator ("drill 3 mm holes").
    pub name: String,
    pub toolpath: Toolpath,
    /// The tool (None for sewing: the needle; a thread colour then changes by number).
    pub tool: Tool,
    /// The tool's name for the operator ("6 mm flat end mill").
    pub tool_name: String,
}

/// The figures of one operation in a joined job.
#[derive(Clone, Debug, PartialEq)]
pub struct StepFigures {
    pub name: String,
    pub tool: Tool,
    pub tool_name: String,
    /// Cutting and rapid length, mm.
    pub cutting: f64,
    pub rapid: f64,
    /// Estimated time at the default kinematics, s.
    pub seconds: f64,
    /// Whether a tool change comes before it.
    pub tool_change: bool,
    /// Where its moves (its tool change first) begin in the joined path.
    pub first_move: usize,
}

/// A tool as an operator reads it: `6 mm flat end mill`.
pub fn tool_name(t: &Tool) -> String {
    let kind = match t.kind {
        ToolKind::FlatEnd => "flat end mill",
        ToolKind::BallEnd => "ball end mill",
        ToolKind::Needle => "needle",
    };
    let d = format!("{:.3}", t.diameter);
    let d = d.trim_end_matches('0').trim_end_matches('.');
    format!("{d} mm {kind}")
}

/// Seconds the spindle is given to come up to speed after a tool change before cutting.
pub const SPIN_UP_SECONDS: f64 = 2.0;

/// Joins the operations' paths in their order into one: it starts by loading the first tool
/// (a tool change before any move); between two operations whose tools differ, the tool goes up to the higher of their safe heights, the spindle stops, the
/// tool changes (a colour change for needles: another thread), and the spindle comes back
/// up with [`SPIN_UP_SECONDS`] of dwell. The joined path names the first tool.
pub fn join(steps: &[Step]) -> (Toolpath, Vec<StepFigures>) {
    let mut out = Toolpath::new(
        steps
            .iter()
            .map(|s| s.name.as_str())
            .collect::<Vec<_>>()
            .join(", then "),
    );
    out.tool = steps.first().and_then(|s| s.toolpath.tool.map(|_| s.tool));
    out.source = steps
        .first()
        .map(|s| s.toolpath.source.clone())
        .unwrap_or_default();
    let mut figures = Vec::new();
    let k = crate::stats::Kinematics::default();
    let mut last: Option<&Step> = None;
    let mut pos = P3::default();
    // the speed the spindle runs at (0: stopped)
    let mut spindle = 0.0;
    for s in steps {
        let needle = s.tool.kind == ToolKind::Needle;
        let first = last.is_none();
        let first_move = out.moves.len();
        // the first tool is loaded too (the operator is asked for it before anything moves);
        // the first thread is simply the one on the machine
        let change = match last {
            None => !needle,
            Some(l) => l.tool.number != s.tool.number,
        };
        if first && change {
            out.push(Move::ToolChange {
                tool: s.tool.number,
                name: s.tool_name.clone(),
                geometry: Some(s.tool),
            });
        } else if change {
            if needle {
                out.push(Move::ColorChange);
            } else {
                let top = highest(&s.toolpath).max(pos.z);
                if pos.z < top {
                    pos = P3::new(pos.x, pos.y, top);
                    out.push(Move::Rapid { to: pos });
                }
                out.push(Move::Spindle { rpm: 0.0 });
                spindle = 0.0;
                out.push(Move::ToolChange {
                    tool: s.tool.number,
                    name: s.tool_name.clone(),
                    geometry: Some(s.tool),
                });
                if let Some(rpm) = first_spindle(&s.toolpath) {
                    out.push(Move::Spindle { rpm });
                    spindle = rpm;
                    out.push(Move::Dwell {
                        seconds: SPIN_UP_SECONDS,
                    });
                }
            }
        }
        out.push(Move::Comment {
            text: format!("{} with T{}: {}", s.name, s.tool.number, s.tool_name),
        });
        let mut moves = s.toolpath.moves.clone();
        // the spindle keeps running from one operation to the next with the same tool: no
        // stop at an operation's end but the job's last, no restart at the same speed
        let is_last = std::ptr::eq(s, steps.last().expect("a step"));
        let mut on = spindle;
        moves.retain(|m| match m {
            Move::Spindle { rpm } if *rpm == 0.0 && !is_last => false,
            Move::Spindle { rpm } if *rpm == on => false,
            Move::Spindle { rpm } => {
                on = *rpm;
                true
            }
            _ => true,
        });
        let part = Toolpath {
            moves,
            ..s.toolpath.clone()
        };
        pos = part.walk(pos, |_, _, _| {});
        spindle = on;
        let st = part.stats(&k);
        out.moves.extend(part.moves);
        out.warnings.extend(
            s.toolpath
                .warnings
                .iter()
                .map(|w| format!("{}: {w}", s.name)),
        );
        figures.push(StepFigures {
            name: s.name.clone(),
            tool: s.tool,
            tool_name: s.tool_name.clone(),
            cutting: st.cutting_length,
            rapid: st.rapid_length,
            seconds: st.time(),
            tool_change: change,
            first_move,
        });
        last = Some(s);
    }
    (out, figures)
}

/// The highest Z a path reaches (0 when it never moves).
fn highest(tp: &Toolpath) -> f64 {
    tp.bounds().map_or(0.0, |b| b.max.z)
}

/// The speed the path first turns its spindle on at.
fn first_spindle(tp: &Toolpath) -> Option<f64> {
    tp.moves.iter().find_map(|m| match m {
        Move::Spindle { rpm } if *rpm > 0.0 => Some(*rpm),
        _ => None,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn globs_match_case_insensitively() {
        assert!(glob("HOLE*", "holes"));
        assert!(glob("*", ""));
        assert!(glob("?-CUT", "A-cut"));
        assert!(!glob("HOLE", "HOLES"));
        assert!(glob("*OUT*", "my_outline"));
        assert!(!glob("P?CKET", "POCKETS"));
    }

    fn step(name: &str, n: u32, d: f64, rpm: f64) -> Step {
        let mut tp = Toolpath::new(name);
        tp.tool = Some(Tool {
            number: n,
            ..Tool::flat(d)
        });
        tp.push(Move::Rapid {
            to: P3::new(0.0, 0.0, 5.0),
        });
        tp.push(Move::Spindle { rpm });
        tp.push(Move::Linear {
            to: P3::new(0.0, 0.0, -1.0),
            feed: 100.0,
        });
        tp.push(Move::Rapid {
            to: P3::new(0.0, 0.0, 5.0),
        });
        Step {
            name: name.into(),
            toolpath: tp,
            tool: Tool {
                number: n,
                ..Tool::flat(d)
            },
            tool_name: format!("{d} mm flat end mill"),
        }
    }

    #[test]
    fn a_tool_change_comes_only_where_the_tool_differs() {
        let (tp, fig) = join(&[
            step("a", 1, 3.0, 10000.0),
            step("b", 2, 6.0, 12000.0),
            step("c", 2, 6.0, 12000.0),
        ]);
        let changes: Vec<u32> = tp
            .moves
            .iter()
            .filter_map(|m| match m {
                Move::ToolChange { tool, .. } => Some(*tool),
                _ => None,
            })
            .collect();
        assert_eq!(changes, vec![1, 2]);
        assert_eq!(
            fig.iter().map(|f| f.tool_change).collect::<Vec<_>>(),
            vec![true, true, false]
        );
        assert!(matches!(tp.moves[0], Move::ToolChange { tool: 1, .. }));
        // the spindle stops before the change and runs at the next speed after it
        let i = tp
            .moves
            .iter()
            .position(|m| matches!(m, Move::ToolChange { tool: 2, .. }))
            .unwrap();
        assert_eq!(tp.moves[i - 1], Move::Spindle { rpm: 0.0 });
        assert_eq!(tp.moves[i + 1], Move::Spindle { rpm: 12000.0 });
        assert!(matches!(tp.moves[i + 2], Move::Dwell { .. }));
    }
}
