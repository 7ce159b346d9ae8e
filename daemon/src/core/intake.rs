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
    /// A job of several operations, in their order, each with its tool and the geometry it
    /// takes (a recipe's list); instead of `operation`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub operations: Vec<crate::core::intake::recipe::JobOperation>,
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
    /// Clear the inside of closed shapes keeping the tool's engagement under a bound.
    Adaptive(offset_core::ops::AdaptiveParams),
    /// Pocket whose feed follows the simulated load (`--op pocket --feed-control`).
    PocketFeedControl(offset_core::cutsim::feed::FeedControlledPocket),
    /// Sew stitches along the shape.
    Stitch(StitchParams),
    /// Drill the circles (and DXF points) the drill's size; bore larger ones.
    Drill(offset_core::ops::DrillParams),
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
            Operation::Pocket(_) | Operation::PocketFeedControl(_) => "pocket",
            Operation::Adaptive(_) => "adaptive",
            Operation::Stitch(_) => "stitch",
            Operation::Drill(_) => "drill",
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
    /// A job of operations: each one's tool, lengths and time.
    pub figures: Vec<crate::core::intake::recipe::OperationFigures>,
}

/// The wall-clock time of each stage of a plan, in the order they ran (`machlink plan
/// --timings` prints them): `read` (the shape file parsed), `import fit` (the geometry
/// JSON's polylines fitted with arcs), `plan` (the operation's geometry), `fit` (the tool
/// path's runs of lines fitted into arcs), `post` (the program's units).
#[derive(Clone, Debug, Default)]
pub struct Stages(pub Vec<(&'static str, std::time::Duration)>);

impl Stages {
    /// Runs `f` and records its time as stage `name`.
    pub fn time<T>(&mut self, name: &'static str, f: impl FnOnce() -> T) -> T {
        let started = std::time::Instant::now();
        let out = f();
        self.add(name, started.elapsed());
        out
    }

    /// Adds `took` to stage `name` (a stage met twice adds up).
    pub fn add(&mut self, name: &'static str, took: std::time::Duration) {
        match self.0.iter_mut().find(|(n, _)| *n == name) {
            Some((_, t)) => *t += took,
            None => self.0.push((name, took)),
        }
    }
}

/// Turns a job into a checked program for `target`. Nothing is sent anywhere: a refused
/// job leaves no trace.
pub fn plan(spec: &JobSpec, target: Target<'_>) -> Result<Planned, IntakeError> {
    plan_timed(spec, target, &mut Stages::default())
}

/// [`plan`], with the time of each stage recorded in `stages`.
pub fn plan_timed(
    spec: &JobSpec,
    target: Target<'_>,
    stages: &mut Stages,
) -> Result<Planned, IntakeError> {
    // a drawing for a machine with a default recipe, and no operation of its own, takes the
    // recipe's operations (read at each plan, so an edited recipe counts from the next job)
    let with_recipe;
    let spec = match target {
        Target::Machine(m)
            if spec.operation.is_none()
                && spec.operations.is_empty()
                && spec.input.kind() == InputKind::Shape =>
        {
            match &m.recipe {
                Some(path) => {
                    with_recipe = JobSpec {
                        operations: crate::core::intake::recipe::Recipe::from_path(path)?
                            .operations,
                        ..spec.clone()
                    };
                    &with_recipe
                }
                None => spec,
            }
        }
        _ => spec,
    };
    if let Some(t) = spec.tolerance {
        check_tolerance(t)?;
    }
    let mut figures = Vec::new();
    let (toolpath, shape, mesh, mut warnings) = match spec.input.kind() {
        InputKind::Gcode => return plan_gcode(spec, target),
        InputKind::Shape if !spec.operations.is_empty() => {
            let p = crate::core::intake::recipe::plan_operations(spec, target)?;
            figures = p.figures;
            (p.toolpath, Some(p.shape), None, p.warnings)
        }
        InputKind::Shape => {
            let (shape, warnings) = read_shape_timed(spec, stages)?;
            let toolpath = toolpath_timed(spec, &shape, stages)?;
            (toolpath, Some(shape), None, warnings)
        }
        InputKind::Mesh | InputKind::Points => {
            let mesh = read_mesh(spec)?;
            let toolpath = toolpath_3d(spec, &mesh)?;
            (toolpath, None, Some(mesh), Vec::new())
        }
    };
    warnings.extend(toolpath.warnings.iter().cloned());
    let toolpath = match target {
        Target::Machine(m) => with_probes(toolpath, m),
        Target::Post(_) => toolpath,
    };
    let post = pick_post(spec, target)?;
    if let Target::Machine(m) = target {
        check::moves(&toolpath, m, &check::planned_move).map_err(IntakeError::Refused)?;
    }
    let program = stages.time("post", || post.program(&toolpath)).map_err(|e| {
        let sews = toolpath
            .moves
            .iter()
            .any(|m| matches!(m, offset_core::Move::Stitch { .. } | offset_core::Move::Jump { .. }));
        match target {
            // stitches the machine's posts cannot write: the job was sent to the wrong machine
            Target::Machine(m) if sews => IntakeError::Refused(format!(
                "machine `{}` is not a sewing machine (link = \"{}\", it runs {}): send stitch jobs to a sewing machine",
                m.name,
                m.link,
                m.kind
                    .posts()
                    .iter()
                    .map(|p| p.name())
                    .collect::<Vec<_>>()
                    .join(", ")
            )),
            _ => IntakeError::Refused(format!("cannot write the {} program: {e}", e.post)),
        }
    })?;
    Ok(Planned {
        program,
        shape,
        mesh,
        warnings,
        operation: match &spec.operation {
            Some(op) => op.name().to_string(),
            None => toolpath.operation.clone(),
        },
        toolpath,
        figures,
    })
}

/// The tool path with a tool-length probe on machine `m`'s touch plate after every tool
/// change, when the machine probes (`probe = true`): the spindle is still stopped there, and
/// the next cut comes after it.
fn with_probes(mut tp: offset_core::Toolpath, m: &MachineConfig) -> offset_core::Toolpath {
    let (true, Some(plate)) = (m.probe, m.touch_plate) else {
        return tp;
    };
    let mut moves = Vec::with_capacity(tp.moves.len() + 4);
    for mv in tp.moves.drain(..) {
        let change = matches!(mv, offset_core::Move::ToolChange { .. });
        moves.push(mv);
        if change {
            moves.push(plate.probe_move());
        }
    }
    tp.moves = moves;
    tp
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

/// An operation's error in words; a contour that crosses itself also names the drawing's
/// entities there (their handles and layers), where the file names them (DXF).
fn crossing_named(spec: &JobSpec, e: offset_core::ops::OpError) -> String {
    use offset_core::offset::OffsetError;
    let offset_core::ops::OpError::Offset(OffsetError::SelfIntersecting { at, .. }) = &e else {
        return e.to_string();
    };
    let Ok(bytes) = spec.input.bytes() else {
        return e.to_string();
    };
    let names = offset_core::io::entities_at(
        &bytes,
        &spec.input.file_name,
        &offset_core::io::ReadOptions {
            layers: spec.layers.clone(),
            tolerance: spec.tolerance.unwrap_or(DEFAULT_TOLERANCE),
            ..Default::default()
        },
        *at,
    );
    if names.is_empty() {
        return e.to_string();
    }
    format!("{e}: {}", names.join(", "))
}

/// Reads the job's shape with its layers and tolerance; the readers' warnings beside it.
pub fn read_shape(spec: &JobSpec) -> Result<(Shape, Vec<String>), IntakeError> {
    read_shape_timed(spec, &mut Stages::default())
}

/// [`read_shape`], timed in `stages` as `read` (the file parsed) and, where the import
/// fits arcs as a step of its own (geometry JSON), `import fit`.
fn read_shape_timed(
    spec: &JobSpec,
    stages: &mut Stages,
) -> Result<(Shape, Vec<String>), IntakeError> {
    let started = std::time::Instant::now();
    let bytes = spec.input.bytes()?;
    let file = &spec.input.file_name;
    let read = offset_core::io::read_shape_timed(
        &bytes,
        file,
        &offset_core::io::ReadOptions {
            layers: spec.layers.clone(),
            tolerance: spec.tolerance.unwrap_or(DEFAULT_TOLERANCE),
            ..Default::default()
        },
    );
    let fit = read.as_ref().ok().and_then(|(_, _, t)| t.fit);
    stages.add(
        "read",
        started.elapsed().saturating_sub(fit.unwrap_or_default()),
    );
    if let Some(fit) = fit {
        stages.add("import fit", fit);
    }
    let (shape, warnings, _) = read.map_err(|e| IntakeError::Input(e.to_string()))?;
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
    toolpath_timed(spec, shape, &mut Stages::default())
}

/// [`toolpath`], its `plan` and `fit` stages timed in `stages`.
fn toolpath_timed(
    spec: &JobSpec,
    shape: &Shape,
    stages: &mut Stages,
) -> Result<Toolpath, IntakeError> {
    let Some(op) = &spec.operation else {
        return Err(IntakeError::Input(format!(
            "{} is a shape file: say which operation to plan (--op profile, pocket, adaptive or stitch)",
            spec.input.file_name
        )));
    };
    let started = std::time::Instant::now();
    let planned = match op {
        Operation::Profile(p) => {
            let mut p = p.clone();
            p.cut.tolerance = spec.tolerance.unwrap_or(p.cut.tolerance);
            offset_core::ops::profile(shape, &p)
                .map_err(|e| format!("cannot plan the profile: {}", crossing_named(spec, e)))
        }
        Operation::Pocket(p) => {
            let mut p = p.clone();
            p.cut.tolerance = spec.tolerance.unwrap_or(p.cut.tolerance);
            offset_core::ops::pocket(shape, &p)
                .map_err(|e| format!("cannot plan the pocket: {}", crossing_named(spec, e)))
        }
        Operation::Adaptive(p) => {
            let mut p = p.clone();
            p.cut.tolerance = spec.tolerance.unwrap_or(p.cut.tolerance);
            offset_core::ops::adaptive(shape, &p).map_err(|e| {
                format!(
                    "cannot plan the adaptive clearing: {}",
                    crossing_named(spec, e)
                )
            })
        }
        Operation::PocketFeedControl(p) => {
            let mut p = p.clone();
            p.pocket.cut.tolerance = spec.tolerance.unwrap_or(p.pocket.cut.tolerance);
            offset_core::cutsim::feed::pocket(shape, &p)
                .map_err(|e| format!("cannot plan the pocket with feed control: {e}"))
        }
        Operation::Stitch(p) => offset_core::stitch::stitch(shape, p)
            .map_err(|e| format!("cannot plan the stitches: {e}")),
        Operation::Drill(p) => {
            // drilled holes are canned cycles: nothing to fit
            let (holes, _) = offset_core::ops::drill::holes_in(shape);
            let mut tp = offset_core::ops::drill(&holes, p)
                .map(|(tp, _)| tp)
                .map_err(|e| IntakeError::Plan(format!("cannot plan the drilling: {e}")))?;
            tp.source = spec.input.file_name.clone();
            stages.add("plan", started.elapsed());
            return Ok(tp);
        }
        other => {
            return Err(IntakeError::Input(format!(
                "{} is a 2D shape: {} plans meshes (.stl) and point grids (.csv)",
                spec.input.file_name,
                other.name()
            )))
        }
    };
    stages.add("plan", started.elapsed());
    let mut tp = planned.map_err(IntakeError::Plan)?;
    tp.source = spec.input.file_name.clone();
    Ok(stages.time("fit", || {
        fitted(tp, spec.tolerance.unwrap_or(DEFAULT_TOLERANCE))
    }))
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
            "{file} is already a G-code program; `plan` takes a shape (.json, .dxf, .svg), a mesh (.stl) or a point grid (.csv): preview, simulate or submit the program as it is"
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
        figures: Vec::new(),
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

pub mod recipe {
    //! A job of several operations (a recipe), planned here beside the single operations
    //! whose planning it calls and which call it back (`plan` hands a job of operations to
    //! `recipe::plan_operations`, which plans each one with `toolpath`): one file, so the
    //! two never import each other.
    //!
    //! Recipes: a job of several operations, each with its own tool (a number from the machine's
    //! `tools` table, or given inline) and the geometry it takes (DXF layers and SVG layers or
    //! groups by name or glob, DXF colours, circles of a diameter range), planned in their order into one tool path with
    //! a tool change wherever the tool differs. A recipe file is that list in TOML, reusable
    //! across parts; `JobSpec.operations` carries the same list in a job.

    use super::{IntakeError, JobSpec, Operation, Target, DEFAULT_TOLERANCE};
    use crate::core::machine::MachineConfig;
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
                return Err(IntakeError::Input(format!("{file} has no [[operations]]")));
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
    fn resolve_tool(
        op: &JobOperation,
        i: usize,
        target: Target<'_>,
    ) -> Result<(Tool, String), IntakeError> {
        let own = match &op.operation {
            Operation::Profile(p) => p.cut.tool,
            Operation::Pocket(p) => p.cut.tool,
            Operation::Adaptive(p) => p.cut.tool,
            Operation::Drill(p) => p.tool,
            Operation::Stitch(_) => Tool {
                number: 1,
                diameter: 0.0,
                kind: ToolKind::Needle,
            },
            other => {
                return Err(IntakeError::Input(format!(
                    "operation {} ({}) plans meshes; a job of operations takes profile, pocket, adaptive, drill and stitch",
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
            return Ok((Tool { number: n, ..own }, format!("thread {n}")));
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
        let lower = file.to_ascii_lowercase();
        let is_dxf = lower.ends_with(".dxf");
        if !is_dxf && !take.colors.is_empty() {
            return Err(IntakeError::Input(format!(
                "{file} is not a DXF file: take.colors selects DXF entities by colour"
            )));
        }
        if !is_dxf && !lower.ends_with(".svg") && !take.layers.is_empty() {
            return Err(IntakeError::Input(format!(
                "{file} is neither a DXF nor an SVG file: take.layers selects DXF layers and SVG layers or groups"
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
                offset_core::ops::drill::circle_of(p)
                    .is_some_and(|(_, r)| take.takes_diameter(2.0 * r))
            });
        }
        Ok((
            shape,
            warnings
                .into_iter()
                .map(|w| format!("{file}: {w}"))
                .collect(),
        ))
    }

    /// The kinds of DXF entity the reader turns into geometry (others are its own warnings).
    const GEOMETRY: [&str; 9] = [
        "LINE",
        "ARC",
        "CIRCLE",
        "LWPOLYLINE",
        "POLYLINE",
        "SPLINE",
        "ELLIPSE",
        "POINT",
        "INSERT",
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
    pub fn plan_operations(
        spec: &JobSpec,
        target: Target<'_>,
    ) -> Result<PlannedOperations, IntakeError> {
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
        // the names take.layers' globs match: DXF layers, SVG groups (Inkscape layer labels
        // and group ids)
        let mut file_layers: Vec<String> = if file.to_ascii_lowercase().ends_with(".svg") {
            offset_core::io::svg::layers(&spec.input.bytes()?, file)
                .map_err(|e| IntakeError::Input(e.to_string()))?
        } else {
            Vec::new()
        };
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
            let plan_err =
                |e: offset_core::ops::OpError| IntakeError::Plan(format!("{label}: {e}"));
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
                    let tp = super::toolpath(&one, &shape).map_err(|e| match e {
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
            if GEOMETRY.contains(&e.kind.as_str())
                && !spec.operations.iter().any(|op| op_takes(op, e))
            {
                warnings.push(format!(
                    "{file}: {} is taken by no operation of the job",
                    e.describe()
                ));
            }
        }
        // an SVG's elements, by the groups they lie in and, for operations that take
        // circles (drilling, a diameter range), by what they draw: a circle of another
        // size than every drill's range is named, never silently left out
        if file.to_ascii_lowercase().ends_with(".svg") {
            let placed = offset_core::io::svg::placed_paths(
                &spec.input.bytes()?,
                file,
                spec.tolerance.unwrap_or(DEFAULT_TOLERANCE),
            )
            .map_err(|e| IntakeError::Input(e.to_string()))?;
            for p in placed {
                let diameter = match p.paths.as_slice() {
                    [one] => offset_core::ops::drill::circle_of(one).map(|(_, r)| 2.0 * r),
                    _ => None,
                };
                let taken = spec.operations.iter().any(|op| {
                    let in_group = op.take.layers.is_empty()
                        || p.groups.iter().any(|g| op.take.takes_layer(g));
                    let drill = matches!(op.operation, Operation::Drill(_));
                    in_group
                        && match diameter {
                            Some(d) => op.take.takes_diameter(d),
                            None => !drill && op.take.diameter.is_none(),
                        }
                });
                if !taken {
                    let what = match diameter {
                        Some(d) => format!("{} (a circle of {d:.3} mm)", p.name),
                        None => p.name.clone(),
                    };
                    let place = match p.groups.first() {
                        Some(_) => format!(" in group {}", p.groups.join(" / ")),
                        None => " outside every group".to_string(),
                    };
                    warnings.push(format!(
                        "{file}: {what}{place} is taken by no operation of the job"
                    ));
                }
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
            Operation::Adaptive(mut p) => {
                p.cut.tool = tool;
                Operation::Adaptive(p)
            }
            Operation::Drill(mut p) => {
                p.tool = tool;
                Operation::Drill(p)
            }
            other => other,
        }
    }
}
