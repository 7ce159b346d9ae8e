//! Intake: one way in for every job. A [`JobSpec`] (the input file, the operation with its
//! own options, the tolerance and layers, the post) and a target (a configured machine, or a
//! post for `machlink plan`) become a checked program. `plan`, `submit` (through the API),
//! `preview` and `demo` all go through [`plan`], so the same flags make the same bytes.

use crate::core::check;
use crate::core::machine::MachineConfig;
use base64::Engine;
use machlink_protocols::{AnyPost, Program};
use offset_core::mesh::{Finish3dParams, Mesh, MeshOptions, Rough3dParams, WaterlineParams};
use offset_core::ops::{PocketParams, ProfileParams};
use offset_core::stitch::StitchParams;
use offset_core::{Shape, Toolpath};
use serde::{Deserialize, Serialize};
use std::sync::Arc;

/// Vertices of one job's shape, all paths together (docs/daemon.md, "Limits").
pub const MAX_SHAPE_VERTICES: usize = 2_000_000;

/// A job as the operator describes it: what `machlink submit` sends to the daemon and
/// `machlink plan` plans offline.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct JobSpec {
    /// The machine to run it on (`submit`; `plan` names none).
    #[serde(default)]
    pub machine: Option<String>,
    /// The file the job comes from.
    pub input: Input,
    /// What to make of a shape; none for a G-code file, which runs as it is.
    #[serde(default)]
    pub operation: Option<Operation>,
    /// The geometric tolerance of every approximation (reading curves, offsets, fitting,
    /// tessellating), mm; none: the operation's own (0.001 for 2D, 0.01 for 3D).
    #[serde(default)]
    pub tolerance: Option<f64>,
    /// DXF: read only the entities on these layers (all when empty).
    #[serde(default)]
    pub layers: Vec<String>,
    /// The post to write the program with; none: the machine's first (`grbl` for `plan`).
    #[serde(default)]
    pub post: Option<String>,
}

/// The tolerance a shape is read with when the job names none, mm.
pub const DEFAULT_TOLERANCE: f64 = 1e-3;

/// A job's input file: its name (whose extension picks the reader) and its bytes, as text
/// or, for binary files, as base64.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Input {
    pub file_name: String,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file_text: Option<String>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub file_base64: Option<String>,
}

/// What kind of file an input is.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InputKind {
    /// Geometry JSON, DXF or SVG: planned by a 2D operation.
    Shape,
    /// A G-code program (.nc, .gcode, .ngc, .tap, .gc, .cnc): checked and run as it is.
    Gcode,
    /// An STL mesh (binary or ASCII): planned by a 3D operation, in the mesh's own frame.
    Mesh,
    /// A grid of measured points (CSV `x,y,z`, rows of equal length): a surface is fitted
    /// through it and planned like a mesh.
    Points,
}

impl Input {
    /// An input of `bytes` named `file_name`: text when it is UTF-8, else base64.
    pub fn from_bytes(file_name: &str, bytes: Vec<u8>) -> Input {
        let (file_text, file_base64) = match String::from_utf8(bytes) {
            Ok(t) => (Some(t), None),
            Err(e) => (
                None,
                Some(base64::engine::general_purpose::STANDARD.encode(e.into_bytes())),
            ),
        };
        Input {
            file_name: file_name.to_string(),
            file_text,
            file_base64,
        }
    }

    /// Reads a file from disk; the input is named by the file's name.
    pub fn from_path(path: &std::path::Path) -> Result<Input, IntakeError> {
        let bytes = std::fs::read(path)
            .map_err(|e| IntakeError::Input(format!("cannot read {}: {e}", path.display())))?;
        let name = path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_else(|| path.display().to_string());
        Ok(Input::from_bytes(&name, bytes))
    }

    /// The file's bytes.
    pub fn bytes(&self) -> Result<Vec<u8>, IntakeError> {
        match (&self.file_text, &self.file_base64) {
            (Some(t), None) => Ok(t.clone().into_bytes()),
            (None, Some(b)) => base64::engine::general_purpose::STANDARD
                .decode(b)
                .map_err(|e| {
                    IntakeError::Input(format!(
                        "file_base64 of {} is not base64: {e}",
                        self.file_name
                    ))
                }),
            _ => Err(IntakeError::Input(format!(
                "give {} as exactly one of file_text and file_base64",
                self.file_name
            ))),
        }
    }

    /// The kind of file, from its extension.
    pub fn kind(&self) -> InputKind {
        let ext = std::path::Path::new(&self.file_name)
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        match ext.as_deref() {
            _ if is_gcode_file(&self.file_name) => InputKind::Gcode,
            Some("stl") => InputKind::Mesh,
            Some("csv") => InputKind::Points,
            _ => InputKind::Shape,
        }
    }
}

/// Whether a file name says G-code, to be run as it is.
pub fn is_gcode_file(name: &str) -> bool {
    let ext = std::path::Path::new(name)
        .extension()
        .and_then(|e| e.to_str())
        .map(|e| e.to_ascii_lowercase());
    matches!(
        ext.as_deref(),
        Some("nc" | "gcode" | "ngc" | "tap" | "gc" | "cnc")
    )
}

/// An operation and its own options (the types of the operation in offset-core; keys left
/// out of a JSON job take the operation's defaults).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(tag = "op", rename_all = "snake_case")]
pub enum Operation {
    /// Cut along the outline, outside, inside or on it.
    Profile(ProfileParams),
    /// Clear the inside of closed shapes, around their islands.
    Pocket(PocketParams),
    /// Sew stitches along the shape.
    Stitch(StitchParams),
    /// 3D: clear a mesh's stock level by level (z-level pockets), leaving an allowance.
    Rough3d(Rough3dParams),
    /// 3D: drop-cutter raster finishing of a mesh, gouge-free.
    Finish3d(Finish3dParams),
    /// 3D: waterline contours of a mesh with a ball cutter.
    Waterline(WaterlineParams),
}

impl Operation {
    /// The operation's name, as `--op` takes it.
    pub fn name(&self) -> &'static str {
        match self {
            Operation::Profile(_) => "profile",
            Operation::Pocket(_) => "pocket",
            Operation::Stitch(_) => "stitch",
            Operation::Rough3d(_) => "rough3d",
            Operation::Finish3d(_) => "finish3d",
            Operation::Waterline(_) => "waterline",
        }
    }

    /// Whether it plans a mesh (true) or a 2D shape (false).
    pub fn is_3d(&self) -> bool {
        matches!(
            self,
            Operation::Rough3d(_) | Operation::Finish3d(_) | Operation::Waterline(_)
        )
    }
}

/// Why a job was not made into a program. Each is one sentence naming what and where.
#[derive(Debug, thiserror::Error)]
pub enum IntakeError {
    /// The input or the spec is wrong (a file that does not read, a missing operation).
    #[error("{0}")]
    Input(String),
    /// The operation could not plan a path.
    #[error("{0}")]
    Plan(String),
    /// The program is refused by the machine's checks (work area, feed, codes) or its post.
    #[error("{0}")]
    Refused(String),
}

/// What a job is planned for.
#[derive(Clone, Copy)]
pub enum Target<'a> {
    /// A configured machine: its kind's posts, and its checks.
    Machine(&'a MachineConfig),
    /// A post alone (`machlink plan` without a machine): nothing to check against.
    Post(&'a Arc<dyn AnyPost>),
}

/// A planned and checked job.
#[derive(Clone, Debug)]
pub struct Planned {
    pub program: Program,
    /// The shape the job was planned from (2D jobs).
    pub shape: Option<Shape>,
    /// The mesh the job was planned from (3D jobs).
    pub mesh: Option<Mesh>,
    /// The moves the program makes (planned, or read from the G-code file).
    pub toolpath: Toolpath,
    /// The readers' and planners' warnings (open contours, skipped entities, …).
    pub warnings: Vec<String>,
    /// The operation's name, or `gcode` for a G-code file.
    pub operation: String,
}

/// Turns a job into a checked program for `target`. Nothing is sent anywhere: a refused
/// job leaves no trace.
pub fn plan(spec: &JobSpec, target: Target<'_>) -> Result<Planned, IntakeError> {
    if let Some(t) = spec.tolerance {
        check_tolerance(t)?;
    }
    let (toolpath, shape, mesh, mut warnings) = match spec.input.kind() {
        InputKind::Gcode => return plan_gcode(spec, target),
        InputKind::Shape => {
            let (shape, warnings) = read_shape(spec)?;
            let toolpath = toolpath(spec, &shape)?;
            (toolpath, Some(shape), None, warnings)
        }
        InputKind::Mesh | InputKind::Points => {
            let mesh = read_mesh(spec)?;
            let toolpath = toolpath_3d(spec, &mesh)?;
            (toolpath, None, Some(mesh), Vec::new())
        }
    };
    warnings.extend(toolpath.warnings.iter().cloned());
    let post = pick_post(spec, target)?;
    if let Target::Machine(m) = target {
        check::moves(&toolpath, m, &check::planned_move).map_err(IntakeError::Refused)?;
    }
    let program = post
        .program(&toolpath)
        .map_err(|e| IntakeError::Refused(format!("cannot write the {} program: {e}", e.post)))?;
    Ok(Planned {
        program,
        shape,
        mesh,
        toolpath,
        warnings,
        operation: spec
            .operation
            .as_ref()
            .map_or("", Operation::name)
            .to_string(),
    })
}

/// Reads the job's mesh: an STL, or a surface fitted through a point grid (for roughing,
/// closed into a solid down to 1 mm below its lowest point).
pub fn read_mesh(spec: &JobSpec) -> Result<Mesh, IntakeError> {
    let bytes = spec.input.bytes()?;
    let file = &spec.input.file_name;
    let err = |e: offset_core::mesh::MeshError| IntakeError::Input(e.to_string());
    match spec.input.kind() {
        InputKind::Points => {
            let tol = spec.tolerance.unwrap_or(0.01);
            let (surface, mesh) =
                offset_core::mesh::mesh_from_points(&bytes, file, tol).map_err(err)?;
            if matches!(spec.operation, Some(Operation::Rough3d(_))) {
                let low = mesh.bounds().map_or(0.0, |(lo, _)| lo.z);
                surface.solid(file, tol, low - 1.0).map_err(err)
            } else {
                Ok(mesh)
            }
        }
        _ => offset_core::mesh::read_stl(&bytes, file, &MeshOptions::default()).map_err(err),
    }
}

/// Plans the job's 3D operation on `mesh`, at the job's tolerance when it names one.
pub fn toolpath_3d(spec: &JobSpec, mesh: &Mesh) -> Result<Toolpath, IntakeError> {
    let file = &spec.input.file_name;
    let planned = match &spec.operation {
        Some(Operation::Rough3d(p)) => {
            let mut p = p.clone();
            p.tolerance = spec.tolerance.unwrap_or(p.tolerance);
            offset_core::mesh::rough3d(mesh, &p)
                .map_err(|e| format!("cannot plan the roughing: {e}"))
        }
        Some(Operation::Finish3d(p)) => {
            let mut p = p.clone();
            p.tolerance = spec.tolerance.unwrap_or(p.tolerance);
            offset_core::mesh::finish3d(mesh, &p)
                .map_err(|e| format!("cannot plan the finishing: {e}"))
        }
        Some(Operation::Waterline(p)) => {
            let mut p = p.clone();
            p.tolerance = spec.tolerance.unwrap_or(p.tolerance);
            offset_core::mesh::waterline3d(mesh, &p)
                .map_err(|e| format!("cannot plan the waterlines: {e}"))
        }
        Some(op) => {
            return Err(IntakeError::Input(format!(
                "{file} is a mesh: {} plans 2D shapes; use --op rough3d, finish3d or waterline",
                op.name()
            )))
        }
        None => {
            return Err(IntakeError::Input(format!(
            "{file} is a mesh: say which operation to plan (--op rough3d, finish3d or waterline)"
        )))
        }
    };
    let mut tp = planned.map_err(IntakeError::Plan)?;
    tp.source = file.clone();
    Ok(fitted(tp, spec.tolerance.unwrap_or(0.01)))
}

fn check_tolerance(t: f64) -> Result<(), IntakeError> {
    if t.is_finite() && t > 0.0 && t <= 10.0 {
        Ok(())
    } else {
        Err(IntakeError::Input(format!(
            "the tolerance must be a number above 0 and at most 10 mm, got {t}"
        )))
    }
}

/// Reads the job's shape with its layers and tolerance; the readers' warnings beside it.
pub fn read_shape(spec: &JobSpec) -> Result<(Shape, Vec<String>), IntakeError> {
    let bytes = spec.input.bytes()?;
    let file = &spec.input.file_name;
    let (shape, warnings) = offset_core::io::read_shape_with(
        &bytes,
        file,
        &offset_core::io::ReadOptions {
            layers: spec.layers.clone(),
            tolerance: spec.tolerance.unwrap_or(DEFAULT_TOLERANCE),
        },
    )
    .map_err(|e| IntakeError::Input(e.to_string()))?;
    let vertices: usize = shape.paths.iter().map(|p| p.vertices.len()).sum();
    if vertices > MAX_SHAPE_VERTICES {
        return Err(IntakeError::Input(format!(
            "{file} has {vertices} vertices, more than the daemon's limit of {} per job",
            MAX_SHAPE_VERTICES
        )));
    }
    Ok((
        shape,
        warnings
            .into_iter()
            .map(|w| format!("{file}: {w}"))
            .collect(),
    ))
}

/// Plans the job's operation on `shape`, at the job's tolerance.
pub fn toolpath(spec: &JobSpec, shape: &Shape) -> Result<Toolpath, IntakeError> {
    let Some(op) = &spec.operation else {
        return Err(IntakeError::Input(format!(
            "{} is a shape file: say which operation to plan (--op profile, pocket or stitch)",
            spec.input.file_name
        )));
    };
    let planned = match op {
        Operation::Profile(p) => {
            let mut p = p.clone();
            p.cut.tolerance = spec.tolerance.unwrap_or(p.cut.tolerance);
            offset_core::ops::profile(shape, &p)
                .map_err(|e| format!("cannot plan the profile: {e}"))
        }
        Operation::Pocket(p) => {
            let mut p = p.clone();
            p.cut.tolerance = spec.tolerance.unwrap_or(p.cut.tolerance);
            offset_core::ops::pocket(shape, &p).map_err(|e| format!("cannot plan the pocket: {e}"))
        }
        Operation::Stitch(p) => offset_core::stitch::stitch(shape, p)
            .map_err(|e| format!("cannot plan the stitches: {e}")),
        other => {
            return Err(IntakeError::Input(format!(
                "{} is a 2D shape: {} plans meshes (.stl) and point grids (.csv)",
                spec.input.file_name,
                other.name()
            )))
        }
    };
    let mut tp = planned.map_err(IntakeError::Plan)?;
    tp.source = spec.input.file_name.clone();
    Ok(fitted(tp, spec.tolerance.unwrap_or(DEFAULT_TOLERANCE)))
}

/// The tool path with its runs of short lines fitted into lines and arcs within `tolerance`
/// (never across a sharp corner), so every post that has arcs gets them.
fn fitted(tp: Toolpath, tolerance: f64) -> Toolpath {
    offset_core::biarc::fit_toolpath(
        &tp,
        &offset_core::biarc::BiarcOptions::with_tolerance(tolerance),
    )
    .0
}

/// The post of a job: the one it names (which the machine must run), else the machine's
/// first, else `grbl`.
fn pick_post(spec: &JobSpec, target: Target<'_>) -> Result<Arc<dyn AnyPost>, IntakeError> {
    match target {
        Target::Post(p) => Ok(p.clone()),
        Target::Machine(m) => {
            let posts = m.kind.posts();
            match &spec.post {
                None => posts.first().cloned().ok_or_else(|| {
                    IntakeError::Refused(format!("machine `{}` runs no post", m.name))
                }),
                Some(name) => posts
                    .iter()
                    .find(|p| p.name() == name)
                    .cloned()
                    .ok_or_else(|| {
                        IntakeError::Refused(format!(
                        "machine `{}` (link = \"{}\") does not run the {name} post (it runs {})",
                        m.name,
                        m.link,
                        posts.iter().map(|p| p.name()).collect::<Vec<_>>().join(", "),
                    ))
                    }),
            }
        }
    }
}

/// A G-code file: checked line by line, and taken by the machine's kind as it is.
fn plan_gcode(spec: &JobSpec, target: Target<'_>) -> Result<Planned, IntakeError> {
    let file = &spec.input.file_name;
    let Target::Machine(m) = target else {
        return Err(IntakeError::Input(format!(
            "{file} is already a G-code program; `plan` takes a shape file (.json, .dxf, .svg)"
        )));
    };
    if let Some(op) = &spec.operation {
        return Err(IntakeError::Input(format!(
            "{file} is a G-code program, which runs as it is: leave out the operation ({})",
            op.name()
        )));
    }
    let text = String::from_utf8(spec.input.bytes()?)
        .map_err(|_| IntakeError::Input(format!("{file} is not a text file")))?;
    let program = check::gcode_program(file, &text, m).map_err(IntakeError::Refused)?;
    let units = m
        .kind
        .gcode(&program.lines, &program.moves)
        .ok_or_else(|| {
            IntakeError::Refused(format!(
                "machine `{}` (link = \"{}\") does not run G-code files",
                m.name, m.link
            ))
        })?;
    let program_units =
        units.map_err(|e| IntakeError::Refused(format!("{file}: cannot make its program: {e}")))?;
    Ok(Planned {
        program: program_units,
        shape: None,
        mesh: None,
        toolpath: program.moves,
        warnings: Vec::new(),
        operation: "gcode".into(),
    })
}

/// What the store keeps of a job's spec: everything but the file's bytes.
pub fn params_of(spec: &JobSpec) -> serde_json::Value {
    let mut v = serde_json::to_value(spec).unwrap_or_default();
    if let Some(input) = v.get_mut("input").and_then(|i| i.as_object_mut()) {
        input.remove("file_text");
        input.remove("file_base64");
    }
    v
}
