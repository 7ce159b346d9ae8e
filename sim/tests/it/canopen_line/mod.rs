//! Three simulated CiA 402 drives (x, y, z on nodes 1–3) run by the real master in
//! lockstep, and a job along one straight line cut into 1 mm moves: the harness of the
//! CANopen stop and disable tests.
#![allow(dead_code)]

use machlink_protocols::kind::{AnyKind, MachineLink, Registry};
use machlink_protocols::{Control, LinkError, LinkEvent, Program, StreamEnd};
use machlink_sim::canopen::kind::SimCanopen;
use machlink_sim::canopen::SyncRecord;
use offset_core::{Move, Toolpath, P3};
use std::sync::Arc;
use std::time::Duration;
use tokio::sync::{mpsc, watch};

pub const PERIOD: f64 = 0.002;
pub const COUNTS: f64 = 1_000_000.0;
/// Each axis's limits: (velocity mm/s, acceleration mm/s², jerk mm/s³).
pub const LIMITS: [(f64, f64, f64); 3] = [
    (60.0, 800.0, 20_000.0),
    (50.0, 600.0, 16_000.0),
    (15.0, 400.0, 10_000.0),
];
pub const SIGN: [f64; 3] = [1.0, -1.0, 1.0];
/// Where the line goes, in `UNITS` moves of equal length.
pub const END: P3 = P3 {
    x: 48.0,
    y: 30.0,
    z: -6.0,
};
pub const UNITS: usize = 57;

pub fn settings(mode: &str) -> serde_json::Value {
    let axis = |name: &str, node: u8, i: usize| {
        serde_json::json!({
            "axis": name, "node": node, "counts_per_mm": COUNTS, "sign": SIGN[i] as i8,
            "max_velocity": LIMITS[i].0, "max_acceleration": LIMITS[i].1, "max_jerk": LIMITS[i].2
        })
    };
    serde_json::json!({
        "lockstep": true,
        "mode": mode,
        "period_ms": 2,
        "heartbeat_ms": 50,
        // 1.5 s, so a loaded machine's late heartbeat is not taken as lost (the test of a
        // silent drive sets 400 ms)
        "heartbeat_timeout_ms": 1500,
        "report_timeout_ms": 2000,
        "axes": [axis("x", 1, 0), axis("y", 2, 1), axis("z", 3, 2)]
    })
}

pub fn line_job() -> Toolpath {
    let mut tp = Toolpath::new("line");
    for k in 1..=UNITS {
        let t = k as f64 / UNITS as f64;
        tp.push(Move::Linear {
            to: P3::new(END.x * t, END.y * t, END.z * t),
            feed: 3000.0,
        });
    }
    tp
}

pub struct Machine {
    registry: Registry,
    pub device: machlink_protocols::kind::Device,
    /// The open link, for what a test asks of it beside streaming (unlock, NMT).
    pub link: Box<dyn MachineLink>,
}

impl Machine {
    pub async fn start(mode: &str) -> Machine {
        Machine::start_with(settings(mode)).await
    }

    /// With the settings `table` (e.g. [`settings`] changed).
    pub async fn start_with(table: serde_json::Value) -> Machine {
        let mut registry = Registry::new();
        machlink_protocols::standard_kinds(&mut registry);
        machlink_sim::kinds::register(&mut registry);
        let kind: Arc<dyn AnyKind> = registry.kind("sim-canopen").expect("registered").clone();
        let settings = kind.settings(table).expect("settings");
        let device = kind.start("line", &settings).await.expect("drives start");
        let link = kind
            .open("line", &settings, &device)
            .await
            .expect("the link opens");
        Machine {
            registry,
            device,
            link,
        }
    }

    pub fn sim(&self) -> &SimCanopen {
        self.device
            .downcast_ref::<SimCanopen>()
            .expect("sim-canopen")
    }

    pub fn program(&self, tp: &Toolpath) -> Program {
        self.registry
            .post("moves")
            .expect("the moves post")
            .program(tp)
            .expect("a program")
    }

    pub async fn stream(
        &mut self,
        program: &Program,
        from: usize,
        mut on_event: impl FnMut(&LinkEvent, &watch::Sender<Control>, &SimCanopen),
    ) -> (Result<StreamEnd, LinkError>, Vec<LinkEvent>) {
        let (tx, mut rx) = mpsc::unbounded_channel();
        let (ctl, ctl_rx) = watch::channel(Control::Run);
        let sim: &SimCanopen = self.device.downcast_ref::<SimCanopen>().unwrap();
        let stream = self.link.stream(program, from, tx, ctl_rx);
        let driver = async {
            let mut seen = Vec::new();
            while let Some(ev) = rx.recv().await {
                on_event(&ev, &ctl, sim);
                seen.push(ev);
            }
            seen
        };
        tokio::time::timeout(Duration::from_secs(120), async {
            tokio::join!(stream, driver)
        })
        .await
        .expect("the stream ends within two minutes")
    }

    /// The set-points every drive applied, joined by SYNC, in mm.
    pub fn setpoints(&self) -> Vec<P3> {
        let traces: Vec<Vec<SyncRecord>> = (1..=3).map(|n| self.sim().drives.trace(n)).collect();
        traces[0]
            .iter()
            .filter_map(|r| {
                let at = |i: usize| traces[i].iter().find(|t| t.sync == r.sync).copied();
                let (y, z) = (at(1)?, at(2)?);
                let mm = |i: usize, c: i32| c as f64 / (SIGN[i] * COUNTS);
                Some(P3::new(mm(0, r.demand), mm(1, y.demand), mm(2, z.demand)))
            })
            .collect()
    }
}
