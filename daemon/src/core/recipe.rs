//! Recipes: a job of several operations, each with its own tool (a number from the machine's
//! `tools` table, or given inline) and the geometry it takes (DXF layers by name or glob,
//! DXF colours, circles of a diameter range), planned in their order into one tool path with
//! a tool change wherever the tool differs. A recipe file is that list in TOML, reusable
//! across parts; `JobSpec.operations` carries the same list in a job.

use crate::core::machine::MachineConfig;
use crate::core::intake::{IntakeError, JobSpec, Operation, Target, DEFAULT_TOLERANCE};
use offset_core::geom::Shape;
use offset_core::io::dxf::DxfEntity;
use offset_core::ops::drill::{holes_in, Hole, Tour};
use offset_core::ops::job::{join, tool_name, Step, StepFigures, Take};
use offset_core::{Tool, ToolKind, Toolpath};
use serde::{Deserialize, Serialize};

/// One operation of a job: what it does (`op = "drill"` and its options), with which tool,
/// on which geometry.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct JobOperation {
    /// A name for the operator (default: the operation's own, `drill`).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// The tool: a number from the machine's `tools` table (`tool = 2`), or the tool itself
    /// (`tool = { number = 2, diameter = 6, name = "6 mm flat end mill" }`, which `plan`
    /// needs: it has no machine). Stitching: the thread's number. None: the operation's
    /// own tool.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub tool: Option<ToolRef>,
    /// The geometry it takes (all of it when empty).
    #[serde(default, skip_serializing_if = "Take::is_all")]
    pub take: Take,
    #[serde(flatten)]
    pub operation: Operation,
}

/// A tool as an operation names it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum ToolRef {
    /// A number from the machine's `tools` table.
    Number(u32),
    Inline(InlineTool),
}

/// A tool given in the recipe itself.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct InlineTool {
    pub number: u32,
    pub diameter: f64,
    #[serde(default)]
    pub kind: ToolKind,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
}

/// A recipe file: `[[operations]]` tables.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Recipe {
    pub operations: Vec<JobOperation>,
}

impl Recipe {
    /// Reads a recipe file (TOML), naming the file and the place of the first error.
    pub fn from_toml(text: &str, file: &str) -> Result<Recipe, IntakeError> {
        let r: Recipe = toml::from_str(text)
            .map_err(|e| IntakeError::Input(format!("{file}: {}", e.to_string().trim())))?;
        if r.operations.is_empty() {
            return Err(IntakeError::Input(format!(
                "{file} has no [[operations]]"
            )));
        }
        Ok(r)
    }

    /// Reads a recipe file from disk.
    pub fn from_path(path: &std::path::Path) -> Result<Recipe, IntakeError> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| IntakeError::Input(format!("cannot read {}: {e}", path.display())))?;
        Recipe::from_toml(&text, &path.display().to_string())
    }
}

/// The figures of one operation of a planned job, for `plan` to print.
#[derive(Clone, Debug, PartialEq)]
pub struct OperationFigures {
    pub figures: StepFigures,
    /// Drilling: the holes and the rapid length of the tour against the file's order.
    pub tour: Option<Tour>,
}

/// A planned job of operations: the joined path, the shape it was planned from, the
/// readers' and planners' warnings, and each operation's figures.
pub struct PlannedOperations {
    pub toolpath: Toolpath,
    pub shape: Shape,
    pub warnings: Vec<String>,
    pub figures: Vec<OperationFigures>,
}

impl JobOperation {
    fn label(&self, i: usize) -> String {
        match &self.name {
            Some(n) => n.clone(),
            None => format!("{} (operation {})", self.operation.name(), i + 1),
        }
    }
}

/// The tool operation `i` runs with, from the recipe and the machine's table.
fn resolve_tool(op: &JobOperation, i: usize, target: Target<'_>) -> Result<(Tool, String), IntakeError> {
    let own = match &op.operation {
        Operation::Profile(p) => p.cut.tool,
        Operation::Pocket(p) => p.cut.tool,
        Operation::Drill(p) => p.tool,
        Operation::Stitch(_) => Tool {
            number: 1,
            diameter: 0.0,
            kind: ToolKind::Needle,
        },
        other => {
            return Err(IntakeError::Input(format!(
                "operation {} ({}) plans meshes; a job of operations takes profile, pocket, drill and stitch",
                i + 1,
                other.name()
            )))
        }
    };
    if let Operation::Stitch(_) = op.operation {
        // a stitching operation's tool is its thread: a colour change between threads
        let n = match &op.tool {
            None => 1,
            Some(ToolRef::Number(n)) => *n,
            Some(ToolRef::Inline(t)) => t.number,
        };
        return Ok((
            Tool { number: n, ..own },
            format!("thread {n}"),
        ));
    }
    let machine = match target {
        Target::Machine(m) => Some(m),
        Target::Post(_) => None,
    };
    let (tool, name) = match &op.tool {
        None => (own, None),
        Some(ToolRef::Number(n)) => {
            let Some(m) = machine else {
                return Err(IntakeError::Input(format!(
                    "{} names tool T{n} from a machine's tool table, and `plan` has no machine: give the tool inline (tool = {{ number = {n}, diameter = … }})",
                    op.label(i)
                )));
            };
            let t = lookup(m, *n, &op.label(i))?;
            (
                Tool {
                    number: *n,
                    diameter: t.diameter,
                    kind: ToolKind::FlatEnd,
                },
                t.name.clone(),
            )
        }
        Some(ToolRef::Inline(t)) => {
            if let Some(m) = machine {
                let have = lookup(m, t.number, &op.label(i))?;
                if (have.diameter - t.diameter).abs() > 1e-6 {
                    return Err(IntakeError::Refused(format!(
                        "{} wants T{} of {} mm, but machine `{}` holds T{} of {} mm",
                        op.label(i),
                        t.number,
                        t.diameter,
                        m.name,
                        t.number,
                        have.diameter
                    )));
                }
            }
            (
                Tool {
                    number: t.number,
                    diameter: t.diameter,
                    kind: t.kind,
                },
                t.name.clone(),
            )
        }
    };
    let name = name.unwrap_or_else(|| tool_name(&tool));
    Ok((tool, name))
}

/// Tool `n` of machine `m`'s table (a machine with no table holds whatever it is given).
fn lookup<'a>(
    m: &'a MachineConfig,
    n: u32,
    who: &str,
) -> Result<std::borrow::Cow<'a, crate::core::machine::ToolConfig>, IntakeError> {
    if m.tools.is_empty() {
        return Err(IntakeError::Refused(format!(
            "{who} names tool T{n}, but machine `{}` has no tools table; add tools = [ {{ number = {n}, diameter = … }} ] to its config",
            m.name
        )));
    }
    m.tools
        .iter()
        .find(|t| t.number == n)
        .map(std::borrow::Cow::Borrowed)
        .ok_or_else(|| {
            IntakeError::Refused(format!(
                "{who} names tool T{n}, which machine `{}` does not have (it has {})",
                m.name,
                m.tools
                    .iter()
                    .map(|t| format!("T{}", t.number))
                    .collect::<Vec<_>>()
                    .join(", ")
            ))
        })
}

/// Reads the part of the job's shape file that `take` selects, with its warnings.
fn read_taken(
    spec: &JobSpec,
    take: &Take,
    file_layers: &[String],
) -> Result<(Shape, Vec<String>), IntakeError> {
    let file = &spec.input.file_name;
    let is_dxf = file.to_ascii_lowercase().ends_with(".dxf");
    if !is_dxf && !(take.layers.is_empty() && take.colors.is_empty()) {
        return Err(IntakeError::Input(format!(
            "{file} is not a DXF file: take.layers and take.colors select DXF entities"
        )));
    }
    take.check()
        .map_err(|e| IntakeError::Input(format!("{file}: {e}")))?;
    let mut layers = if take.layers.is_empty() {
        spec.layers.clone()
    } else {
        take.layers_of(file_layers)
    };
    if !take.layers.is_empty() && layers.is_empty() {
        return Ok((Shape::default(), Vec::new()));
    }
    if !spec.layers.is_empty() && !take.layers.is_empty() {
        layers.retain(|l| spec.layers.iter().any(|s| s.eq_ignore_ascii_case(l)));
    }
    let bytes = spec.input.bytes()?;
    let (mut shape, warnings) = offset_core::io::read_shape_with(
        &bytes,
        file,
        &offset_core::io::ReadOptions {
            layers,
            tolerance: spec.tolerance.unwrap_or(DEFAULT_TOLERANCE),
            colors: take.colors.clone(),
        },
    )
    .map_err(|e| IntakeError::Input(e.to_string()))?;
    if take.diameter.is_some() {
        shape.paths.retain(|p| {
            offset_core::ops::drill::circle_of(p).is_some_and(|(_, r)| take.takes_diameter(2.0 * r))
        });
    }
    Ok((
        shape,
        warnings.into_iter().map(|w| format!("{file}: {w}")).collect(),
    ))
}

/// The kinds of DXF entity the reader turns into geometry (others are its own warnings).
const GEOMETRY: [&str; 9] = [
    "LINE", "ARC", "CIRCLE", "LWPOLYLINE", "POLYLINE", "SPLINE", "ELLIPSE", "POINT", "INSERT",
];

/// Whether operation `op` takes DXF entity `e`.
fn op_takes(op: &JobOperation, e: &DxfEntity) -> bool {
    let drill = matches!(op.operation, Operation::Drill(_));
    op.take.takes(e)
        && if drill {
            matches!(e.kind.as_str(), "CIRCLE" | "POINT")
        } else {
            e.kind != "POINT"
        }
}

/// Plans a job of operations on its shape file for `target`.
pub fn plan_operations(spec: &JobSpec, target: Target<'_>) -> Result<PlannedOperations, IntakeError> {
    let file = &spec.input.file_name;
    if spec.operation.is_some() {
        return Err(IntakeError::Input(
            "give either one operation or a list of operations, not both".into(),
        ));
    }
    let entities = if file.to_ascii_lowercase().ends_with(".dxf") {
        offset_core::io::dxf::entities(&spec.input.bytes()?, file)
            .map_err(|e| IntakeError::Input(e.to_string()))?
    } else {
        Vec::new()
    };
    let mut file_layers: Vec<String> = Vec::new();
    for e in &entities {
        if !file_layers.iter().any(|l| l.eq_ignore_ascii_case(&e.layer)) {
            file_layers.push(e.layer.clone());
        }
    }
    let mut warnings = Vec::new();
    let mut steps = Vec::new();
    let mut tours = Vec::new();
    for (i, op) in spec.operations.iter().enumerate() {
        let label = op.label(i);
        let (tool, tool_name) = resolve_tool(op, i, target)?;
        let (shape, w) = read_taken(spec, &op.take, &file_layers)?;
        for x in w {
            if !warnings.contains(&x) {
                warnings.push(x);
            }
        }
        let points: Vec<&DxfEntity> = entities
            .iter()
            .filter(|e| e.kind == "POINT" && op_takes(op, e))
            .collect();
        let plan_err = |e: offset_core::ops::OpError| IntakeError::Plan(format!("{label}: {e}"));
        let (mut tp, tour) = match &op.operation {
            Operation::Drill(p) => {
                let (mut holes, _) = holes_in(&shape);
                for h in &mut holes {
                    if let Some(e) = entities.iter().find(|e| {
                        e.kind == "CIRCLE"
                            && e.center.is_some_and(|c| c.dist(h.center) < 1e-6)
                            && (e.diameter - h.diameter).abs() < 1e-6
                    }) {
                        h.name = e.describe();
                    }
                }
                holes.extend(points.iter().map(|e| Hole {
                    center: e.center.unwrap_or_default(),
                    diameter: 0.0,
                    name: e.describe(),
                }));
                if holes.is_empty() {
                    warnings.push(format!("{label} takes nothing from {file}"));
                    continue;
                }
                let p = offset_core::ops::DrillParams { tool, ..p.clone() };
                let (tp, t) = offset_core::ops::drill(&holes, &p).map_err(plan_err)?;
                (tp, Some(t))
            }
            other => {
                if shape.paths.is_empty() {
                    warnings.push(format!("{label} takes nothing from {file}"));
                    continue;
                }
                let mut one = spec.clone();
                one.operations.clear();
                one.operation = Some(with_tool(other.clone(), tool));
                let tp = crate::core::intake::toolpath(&one, &shape).map_err(|e| match e {
                    IntakeError::Plan(m) => IntakeError::Plan(format!("{label}: {m}")),
                    e => e,
                })?;
                (tp, None)
            }
        };
        tp.source = file.clone();
        if tp.operation.is_empty() {
            tp.operation = op.operation.name().into();
        }
        steps.push(Step {
            name: label,
            toolpath: tp,
            tool,
            tool_name,
        });
        tours.push(tour);
    }
    // every entity some operation takes, or named
    for e in &entities {
        if GEOMETRY.contains(&e.kind.as_str()) && !spec.operations.iter().any(|op| op_takes(op, e)) {
            warnings.push(format!(
                "{file}: {} is taken by no operation of the job",
                e.describe()
            ));
        }
    }
    if steps.is_empty() {
        return Err(IntakeError::Plan(format!(
            "no operation of the job takes anything from {file}"
        )));
    }
    let (toolpath, figures) = join(&steps);
    let whole = read_taken(spec, &Take::default(), &file_layers)?.0;
    Ok(PlannedOperations {
        toolpath,
        shape: whole,
        warnings,
        figures: figures
            .into_iter()
            .zip(tours)
            .map(|(figures, tour)| OperationFigures { figures, tour })
            .collect(),
    })
}

/// The operation with its tool set to `tool`.
fn with_tool(op: Operation, tool: Tool) -> Operation {
    match op {
        Operation::Profile(mut p) => {
            p.cut.tool = tool;
            Operation::Profile(p)
        }
        Operation::Pocket(mut p) => {
            p.cut.tool = tool;
            Operation::Pocket(p)
        }
        Operation::Drill(mut p) => {
            p.tool = tool;
            Operation::Drill(p)
        }
        other => other,
    }
}
