//! The shop-floor dashboard: one web page (daemon/web, embedded in the binary) served on the
//! API's own listeners, and the two read-outs it needs beyond the API: a job's path unit by
//! unit (`GET /jobs/{id}/path`) and a plan that is not queued (`POST /plan`).
//!
//! The page's three files are the only routes anyone may fetch without a token (`Need::Page`
//! in `services::access::ROUTES`): they hold no data. Everything the page shows or does, it asks of the
//! API with the token the operator typed (sent as the bearer, kept in the tab's session
//! storage), so the route table and the audit log see the page as they see `machlink`.
//! No cookie is set, nothing is fetched from elsewhere (docs/dashboard.md).

use crate::core::intake::JobSpec;
use crate::core::planner::PlanError;
use crate::core::store::JobId;
use crate::faces::api::error::ApiError;
use crate::faces::api::state::AppState;
use axum::extract::{Extension, Path, Request, State};
use axum::http::{header, HeaderValue, StatusCode};
use axum::response::{IntoResponse, Response};
use axum::routing::{get, post};
use axum::{Json, Router};
use machlink_protocols::modbus::{BlockKind, MotionBlock};
use machlink_protocols::sewing::{StitchKind, StitchRecord};
use machlink_protocols::Program;
use offset_core::toolpath::{Move, Toolpath, P3};
use serde::{Deserialize, Serialize};

/// The page, its script and its style sheet, as served.
pub const PAGE: &str = include_str!("../../web/index.html");
pub const SCRIPT: &str = include_str!("../../web/app.js");
pub const STYLE: &str = include_str!("../../web/style.css");

/// What the page may load: its own files and its own API, nothing else (no CDN, no inline
/// script), and it may not be framed.
const POLICY: &str = "default-src 'none'; script-src 'self'; style-src 'self'; img-src 'self' data:; connect-src 'self'; form-action 'none'; frame-ancestors 'none'; base-uri 'none'";

/// The page's routes, merged into the API's router (behind its route table).
pub fn routes() -> Router<AppState> {
    Router::new()
        .route(
            "/",
            get(|| async { file(PAGE, "text/html; charset=utf-8") }),
        )
        .route(
            "/dashboard/app.js",
            get(|| async { file(SCRIPT, "text/javascript; charset=utf-8") }),
        )
        .route(
            "/dashboard/style.css",
            get(|| async { file(STYLE, "text/css; charset=utf-8") }),
        )
        .route("/jobs/{id}/path", get(job_path))
        .route("/plan", post(plan))
}

fn file(body: &'static str, kind: &'static str) -> Response {
    let mut r = body.into_response();
    let h = r.headers_mut();
    h.insert(header::CONTENT_TYPE, HeaderValue::from_static(kind));
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(POLICY),
    );
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(header::CACHE_CONTROL, HeaderValue::from_static("no-cache"));
    h.insert(
        header::REFERRER_POLICY,
        HeaderValue::from_static("no-referrer"),
    );
    r
}

/// A program drawn unit by unit: `ends[i]` is how many of `points` the first `i + 1` units
/// reach, so the part done after `acked` units is `points[..ends[acked - 1]]`; `cut[k]` says
/// whether the segment into `points[k]` cuts (or sews) rather than travels.
#[derive(Clone, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct UnitPath {
    pub total: usize,
    /// X, Y in mm, rounded to a micrometre.
    pub points: Vec<[f64; 2]>,
    pub cut: Vec<bool>,
    pub ends: Vec<usize>,
    /// Lower-left and upper-right corner of the points, mm.
    pub bounds: [f64; 4],
}

/// Every unit of `program` as type `U`, read from its pages if it is kept in the store.
fn all_units<U: machlink_protocols::Unit>(program: &Program) -> Option<Vec<U>> {
    program.view::<U>()?.to_vec().ok()
}

/// The move each unit of `program` makes (None: it does not move, as a spindle word or a
/// trim), for the program units this daemon's posts make: G-code lines, motion blocks,
/// stitch records and CANopen moves. None for a unit type it does not know.
pub fn unit_moves(program: &Program) -> Option<Vec<Option<Move>>> {
    if let Some(lines) = all_units::<String>(program) {
        let mut reader = machlink_protocols::gcode_read::Reader::default();
        return Some(
            lines
                .iter()
                .map(|l| reader.line(l).ok().flatten())
                .collect(),
        );
    }
    if let Some(records) = all_units::<StitchRecord>(program) {
        return Some(
            records
                .iter()
                .map(|r| match r.kind {
                    StitchKind::Stitch => Some(Move::Stitch { to: r.mm() }),
                    StitchKind::Jump => Some(Move::Jump { to: r.mm() }),
                    _ => None,
                })
                .collect(),
        );
    }
    if let Some(moves) = all_units::<Move>(program) {
        return Some(moves.iter().cloned().map(Some).collect());
    }
    let blocks = all_units::<MotionBlock>(program)?;
    let mut at = P3::default();
    Some(
        blocks
            .iter()
            .map(|b| {
                let to = P3::new(
                    b.target[0] as f64 / 1000.0,
                    b.target[1] as f64 / 1000.0,
                    b.target[2] as f64 / 1000.0,
                );
                let feed = b.feed as f64 / 1000.0;
                let m = match b.kind {
                    BlockKind::Rapid => Some(Move::Rapid { to }),
                    BlockKind::Linear => Some(Move::Linear { to, feed }),
                    BlockKind::ArcCw | BlockKind::ArcCcw => Some(Move::Arc {
                        to,
                        center: offset_core::geom::Point::new(
                            at.x + b.center[0] as f64 / 1000.0,
                            at.y + b.center[1] as f64 / 1000.0,
                        ),
                        ccw: b.kind == BlockKind::ArcCcw,
                        feed,
                    }),
                    BlockKind::Dwell | BlockKind::End | BlockKind::ToolChange => None,
                };
                if m.is_some() {
                    at = to;
                }
                m
            })
            .collect(),
    )
}

/// The path of `moves` (one per unit), arcs drawn as chords of at most 10°.
pub fn unit_path(moves: &[Option<Move>]) -> UnitPath {
    let mut out = UnitPath {
        total: moves.len(),
        ..Default::default()
    };
    let mut at = P3::default();
    let round = |v: f64| (v * 1000.0).round() / 1000.0;
    let push = |out: &mut UnitPath, x: f64, y: f64, cut: bool| {
        out.points.push([round(x), round(y)]);
        out.cut.push(cut);
    };
    out.points.push([0.0, 0.0]);
    out.cut.push(false);
    for m in moves {
        if let Some(m) = m {
            match m {
                Move::Rapid { to } => push(&mut out, to.x, to.y, false),
                Move::Linear { to, .. } => push(&mut out, to.x, to.y, true),
                Move::Stitch { to } => push(&mut out, to.x, to.y, true),
                Move::Jump { to } => push(&mut out, to.x, to.y, false),
                Move::Arc {
                    to, center, ccw, ..
                } => {
                    let a0 = (at.y - center.y).atan2(at.x - center.x);
                    let mut a1 = (to.y - center.y).atan2(to.x - center.x);
                    if *ccw && a1 <= a0 + 1e-12 {
                        a1 += std::f64::consts::TAU;
                    }
                    if !*ccw && a1 >= a0 - 1e-12 {
                        a1 -= std::f64::consts::TAU;
                    }
                    let r = ((at.x - center.x).powi(2) + (at.y - center.y).powi(2)).sqrt();
                    let n = (((a1 - a0).abs() / 10f64.to_radians()).ceil() as usize).max(1);
                    for k in 1..n {
                        let a = a0 + (a1 - a0) * k as f64 / n as f64;
                        push(
                            &mut out,
                            center.x + r * a.cos(),
                            center.y + r * a.sin(),
                            true,
                        );
                    }
                    push(&mut out, to.x, to.y, true);
                }
                _ => {}
            }
            at = match m {
                Move::Rapid { to } | Move::Linear { to, .. } | Move::Arc { to, .. } => *to,
                Move::Stitch { to } | Move::Jump { to } => P3::at_z(*to, at.z),
                _ => at,
            };
        }
        out.ends.push(out.points.len());
    }
    let (mut lo, mut hi) = ([f64::MAX; 2], [f64::MIN; 2]);
    for p in &out.points {
        for i in 0..2 {
            lo[i] = lo[i].min(p[i]);
            hi[i] = hi[i].max(p[i]);
        }
    }
    out.bounds = [lo[0], lo[1], hi[0], hi[1]];
    out
}

fn program_path(program: &Program) -> Result<(UnitPath, Vec<Option<Move>>), ApiError> {
    let moves = unit_moves(program).ok_or_else(|| {
        ApiError(
            StatusCode::NOT_IMPLEMENTED,
            format!(
                "the dashboard cannot draw a program of the `{}` post",
                program.post()
            ),
        )
    })?;
    Ok((unit_path(&moves), moves))
}

/// `GET /jobs/{id}/path`: the job's program drawn unit by unit, for the page's preview.
async fn job_path(
    State(st): State<AppState>,
    Path(id): Path<String>,
) -> Result<Response, ApiError> {
    let id: JobId = id.parse().map_err(|_| {
        ApiError(
            StatusCode::BAD_REQUEST,
            format!("`{id}` is not a job number"),
        )
    })?;
    let job = st.sched.job(id)?;
    let m = st.sched.machine_config(&job.machine)?;
    let program = st
        .sched
        .store()
        .program(id)
        .and_then(|p| p.decode(m.kind.as_ref()))
        .map_err(|e| ApiError(StatusCode::INTERNAL_SERVER_ERROR, e.to_string()))?;
    Ok(Json(program_path(&program)?.0).into_response())
}

/// The answer of `POST /plan`: what `machlink plan` prints, and the path to draw.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct PlanPreview {
    pub machine: String,
    pub operation: String,
    pub post: String,
    pub units: usize,
    pub warnings: Vec<String>,
    pub stats: offset_core::stats::PlanStats,
    /// The machine's kind's own estimate of the time it takes, s (when it makes one).
    pub estimate_s: Option<f64>,
    pub path: UnitPath,
}

/// `POST /plan`: a job planned and checked for its machine exactly as `POST /jobs` plans it
/// (same `JobSpec`, same forked planner, same checks), and not stored: the page's preview
/// before it queues the job.
async fn plan(
    State(st): State<AppState>,
    Extension(who): Extension<crate::services::access::Principal>,
    req: Request,
) -> Result<Response, ApiError> {
    let body = crate::faces::api::limits::json_body(req).await?;
    let spec: JobSpec = serde_json::from_slice(&body).map_err(|e| {
        ApiError(
            StatusCode::BAD_REQUEST,
            format!("the request is not a valid job: {e}"),
        )
    })?;
    drop(body);
    let Some(name) = spec.machine.clone() else {
        return Err(ApiError(
            StatusCode::BAD_REQUEST,
            "the job names no machine (give \"machine\")".into(),
        ));
    };
    let machine = st.sched.machine_config(&name)?.clone();
    st.access
        .check_operate(&who, &name, &crate::faces::api::gate::open_jobs(&st.sched))?;
    let planned = {
        let _turn = st.plans.acquire().await.map_err(|e| {
            ApiError(
                StatusCode::SERVICE_UNAVAILABLE,
                format!("the daemon is stopping: {e}"),
            )
        })?;
        crate::core::planner::plan_isolated(
            spec,
            machine.clone(),
            st.planner,
            crate::core::planner::PLAN_TIME_LIMIT,
        )
        .await
    };
    let planned = planned.map_err(|e| match e {
        PlanError::Intake(crate::core::intake::IntakeError::Input(m)) => {
            ApiError(StatusCode::BAD_REQUEST, m)
        }
        PlanError::Broken(m) => ApiError(StatusCode::INTERNAL_SERVER_ERROR, m),
        other => ApiError(StatusCode::UNPROCESSABLE_ENTITY, other.to_string()),
    })?;
    let (path, moves) = program_path(&planned.program)?;
    let mut tp = Toolpath::new(&planned.operation);
    for m in moves.into_iter().flatten() {
        tp.push(m);
    }
    let stats = tp.stats(&offset_core::stats::Kinematics::default());
    Ok(Json(PlanPreview {
        machine: name,
        operation: planned.operation,
        post: planned.program.post().to_string(),
        units: planned.program.len(),
        warnings: planned.warnings,
        stats,
        estimate_s: machine.kind.estimate(&machine.settings, &planned.program),
        path,
    })
    .into_response())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_gcode_program_is_drawn_unit_by_unit_with_its_arcs_as_chords() {
        let lines: Vec<String> = [
            "G21 G90",
            "G0 X10 Y0",
            "G1 X20 F600",
            "G2 X30 Y0 I5 J0",
            "M5",
        ]
        .iter()
        .map(|s| s.to_string())
        .collect();
        let p = unit_path(&unit_moves(&Program::new("grbl", lines)).unwrap());
        assert_eq!(p.total, 5);
        // the origin, the rapid, the line, the half circle in 18 chords; M5 adds nothing
        assert_eq!(p.ends, vec![1, 2, 3, 21, 21]);
        assert_eq!(p.points[2], [20.0, 0.0]);
        assert_eq!(p.points[20], [30.0, 0.0]);
        assert!(!p.cut[1] && p.cut[2] && p.cut[20]);
        // a clockwise arc from (20,0) about (25,0) passes over the top: y up to 5
        assert!((p.bounds[3] - 5.0).abs() < 1e-3, "{:?}", p.bounds);
        for q in &p.points[3..21] {
            let r = ((q[0] - 25.0).powi(2) + q[1].powi(2)).sqrt();
            assert!((r - 5.0).abs() < 2e-3, "{q:?} is {r} mm from the centre");
        }
    }

    #[test]
    fn stitch_records_and_motion_blocks_are_drawn_where_they_go() {
        let records = vec![
            StitchRecord::new(StitchKind::Jump, 100, 0),
            StitchRecord::new(StitchKind::Stitch, 100, 25),
        ];
        let p = unit_path(&unit_moves(&Program::new("dst", records)).unwrap());
        assert_eq!(p.points[1..], [[10.0, 0.0], [10.0, 2.5]]);
        assert_eq!(p.cut[1..], [false, true]);
        let blocks = vec![MotionBlock {
            kind: BlockKind::Linear,
            target: [1500, -2000, 0],
            feed: 600_000,
            center: [0, 0],
        }];
        let p = unit_path(&unit_moves(&Program::new("modbus", blocks)).unwrap());
        assert_eq!(p.points[1], [1.5, -2.0]);
        assert_eq!(p.bounds, [0.0, -2.0, 1.5, 0.0]);
    }
}
