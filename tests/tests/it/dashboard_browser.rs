//! The dashboard in a real browser: Debian's chromium, headless, driven by chromedriver over
//! WebDriver, against a daemon on TLS with simulated GRBL, Modbus, sewing and CANopen
//! machines. The page loads with a token; the four machines show their states; a job
//! submitted from the page advances there as the simulator executes it; Pause on the page
//! holds the simulated machine; a thread break shows "needs operator"; a viewer's page has no
//! enabled action and its forged requests get 403; after a daemon restart the page reconnects
//! by itself. Screenshots at 1280×800 and 800×1280 go to target/dashboard/.
//!
//! chromium and chromedriver must be installed (`.ci/run` installs them): without them the
//! test fails, naming what is missing.

use crate::common;

use common::*;
use machlink::core::store::JobState;
use machlink::daemon::{Daemon, StartOptions, TcpSecurity};
use machlink::faces::client::{Client, Endpoint};
use machlink::services::access::{hex, new_token, token_hash};
use machlink_sim::grbl::GrblSimHandle;
use machlink_sim::sewing::SewingSim;
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

/// A small WebDriver client (W3C protocol, JSON over HTTP/1.1 with hyper) and the
/// chromedriver it talks to.
mod webdriver {
    use http_body_util::{BodyExt, Full};
    use hyper::body::Bytes;
    use serde_json::{json, Value};
    use std::path::{Path, PathBuf};
    use std::time::Duration;

    /// The W3C name of an element reference in JSON.
    pub const ELEMENT: &str = "element-6066-11e4-a52e-4f735466cecf";

    /// Where `name` is on PATH, if anywhere.
    pub fn find_program(name: &str) -> Option<PathBuf> {
        let path = std::env::var_os("PATH")?;
        std::env::split_paths(&path)
            .map(|d| d.join(name))
            .find(|p| p.is_file())
    }

    /// chromedriver, running on a loopback port until dropped.
    pub struct Driver {
        child: std::process::Child,
        pub port: u16,
    }

    impl Drop for Driver {
        /// Ends chromedriver and the browsers it started (its process group), even when the
        /// test failed half way.
        fn drop(&mut self) {
            let group = nix::unistd::Pid::from_raw(self.child.id() as i32);
            let _ = nix::sys::signal::killpg(group, nix::sys::signal::Signal::SIGKILL);
            let _ = self.child.wait();
        }
    }

    impl Driver {
        pub async fn start(program: &Path) -> Driver {
            let port = super::free_port();
            use std::os::unix::process::CommandExt;
            let child = std::process::Command::new(program)
                .arg(format!("--port={port}"))
                .process_group(0)
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::null())
                .spawn()
                .unwrap_or_else(|e| panic!("cannot start {}: {e}", program.display()));
            let d = Driver { child, port };
            for _ in 0..200 {
                if let Ok(v) = request(port, "GET", "/status", None).await {
                    if v["value"]["ready"] == true {
                        return d;
                    }
                }
                tokio::time::sleep(Duration::from_millis(50)).await;
            }
            panic!("chromedriver did not become ready on port {port} within 10 s");
        }
    }

    /// One WebDriver request; the answer's JSON, or the driver's error as a sentence (also
    /// when it takes over 60 s).
    pub async fn request(
        port: u16,
        method: &str,
        path: &str,
        body: Option<Value>,
    ) -> Result<Value, String> {
        tokio::time::timeout(
            Duration::from_secs(60),
            request_once(port, method, path, body),
        )
        .await
        .unwrap_or_else(|_| Err(format!("{method} {path}: no answer within 60 s")))
    }

    async fn request_once(
        port: u16,
        method: &str,
        path: &str,
        body: Option<Value>,
    ) -> Result<Value, String> {
        let tcp = tokio::net::TcpStream::connect(("127.0.0.1", port))
            .await
            .map_err(|e| format!("chromedriver on port {port}: {e}"))?;
        let (mut send, conn) =
            hyper::client::conn::http1::handshake(hyper_util::rt::TokioIo::new(tcp))
                .await
                .map_err(|e| e.to_string())?;
        tokio::spawn(conn);
        let bytes = body.map(|b| b.to_string()).unwrap_or_default();
        let req = hyper::Request::builder()
            .method(method)
            .uri(path)
            .header("host", format!("127.0.0.1:{port}"))
            .header("content-type", "application/json; charset=utf-8")
            .body(Full::new(Bytes::from(bytes)))
            .map_err(|e| e.to_string())?;
        let resp = send.send_request(req).await.map_err(|e| e.to_string())?;
        let status = resp.status();
        let body = resp
            .into_body()
            .collect()
            .await
            .map_err(|e| e.to_string())?
            .to_bytes();
        let v: Value = serde_json::from_slice(&body).map_err(|e| e.to_string())?;
        if !status.is_success() {
            return Err(format!("{method} {path}: {status} {}", v["value"]));
        }
        Ok(v)
    }

    /// A browser session.
    pub struct Session {
        port: u16,
        id: String,
    }

    impl Session {
        pub async fn new(driver: &Driver, chromium: &Path, profile: &Path) -> Session {
            let caps = json!({ "capabilities": { "alwaysMatch": {
                "browserName": "chrome",
                "acceptInsecureCerts": true,
                "goog:chromeOptions": {
                    "binary": chromium,
                    "args": [
                        "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
                        "--no-first-run", "--disable-background-networking",
                        "--disable-component-update", "--disable-sync",
                        "--disable-dev-shm-usage", "--window-size=1280,800",
                        format!("--user-data-dir={}", profile.display()),
                    ],
                },
            }}});
            let v = request(driver.port, "POST", "/session", Some(caps))
                .await
                .unwrap_or_else(|e| panic!("chromium does not start under chromedriver: {e}"));
            Session {
                port: driver.port,
                id: v["value"]["sessionId"].as_str().unwrap().to_string(),
            }
        }

        pub async fn cmd(&self, method: &str, path: &str, body: Option<Value>) -> Value {
            let full = format!("/session/{}{path}", self.id);
            request(self.port, method, &full, body)
                .await
                .unwrap_or_else(|e| panic!("WebDriver: {e}"))["value"]
                .clone()
        }

        pub async fn goto(&self, url: &str) {
            self.cmd("POST", "/url", Some(json!({ "url": url }))).await;
        }

        /// Runs `script` (a function body) in the page with `args`; its return value.
        pub async fn js(&self, script: &str, args: Value) -> Value {
            self.cmd(
                "POST",
                "/execute/sync",
                Some(json!({ "script": script, "args": args })),
            )
            .await
        }

        /// Like `js`, for a script that calls `arguments[arguments.length - 1]` when done.
        pub async fn js_async(&self, script: &str, args: Value) -> Value {
            self.cmd(
                "POST",
                "/execute/async",
                Some(json!({ "script": script, "args": args })),
            )
            .await
        }

        pub async fn find(&self, css: &str) -> String {
            let v = self
                .cmd(
                    "POST",
                    "/element",
                    Some(json!({ "using": "css selector", "value": css })),
                )
                .await;
            v[ELEMENT]
                .as_str()
                .unwrap_or_else(|| panic!("WebDriver found no element `{css}`: {v}"))
                .to_string()
        }

        pub async fn click(&self, css: &str) {
            let e = self.find(css).await;
            self.cmd("POST", &format!("/element/{e}/click"), Some(json!({})))
                .await;
        }

        pub async fn type_into(&self, css: &str, text: &str) {
            let e = self.find(css).await;
            self.cmd(
                "POST",
                &format!("/element/{e}/value"),
                Some(json!({ "text": text })),
            )
            .await;
        }

        /// A PNG of the page at `width` × `height` CSS pixels.
        pub async fn screenshot(&self, width: u32, height: u32) -> Vec<u8> {
            self.cmd(
                "POST",
                "/goog/cdp/execute",
                Some(
                    json!({ "cmd": "Emulation.setDeviceMetricsOverride", "params": {
                    "width": width, "height": height, "deviceScaleFactor": 1, "mobile": false } }),
                ),
            )
            .await;
            self.js("window.scrollTo(0, 0);", json!([])).await;
            tokio::time::sleep(Duration::from_millis(400)).await;
            let b64 = self.cmd("GET", "/screenshot", None).await;
            use base64::Engine;
            base64::engine::general_purpose::STANDARD
                .decode(b64.as_str().unwrap())
                .unwrap()
        }

        pub async fn quit(self) {
            let _ = request(self.port, "DELETE", &format!("/session/{}", self.id), None).await;
        }
    }
}

use webdriver::{find_program, Driver, Session};

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

const BREAK_AT: u32 = 40;

fn machines() -> String {
    format!(
        "[[machine]]\nname = \"router\"\nlink = \"sim-grbl\"\ntime_scale = 1.0\n\n\
         [[machine]]\nname = \"press\"\nlink = \"sim-modbus\"\ntime_scale = 20.0\n\n\
         [[machine]]\nname = \"sewer\"\nlink = \"sim-sewing\"\ntime_scale = 5\nspm = 3000\n\
         thread_break_at = [{BREAK_AT}]\n\n\
         [[machine]]\nname = \"gantry\"\nlink = \"sim-canopen\"\nperiod_ms = 2\nheartbeat_ms = 50\n\
         heartbeat_timeout_ms = 1500\nreport_timeout_ms = 2000\naxes = [\n  \
         {{ axis = \"x\", node = 1, counts_per_mm = 1000, max_velocity = 60, max_acceleration = 800, max_jerk = 20000 }},\n  \
         {{ axis = \"y\", node = 2, counts_per_mm = 1000, max_velocity = 50, max_acceleration = 600, max_jerk = 20000 }},\n  \
         {{ axis = \"z\", node = 3, counts_per_mm = 1000, max_velocity = 15, max_acceleration = 400, max_jerk = 20000 }},\n]\n"
    )
}

/// A CA and a certificate it signed for 127.0.0.1, as PEM files: (CA, certificate, key).
/// The browser accepts it as an untrusted certificate; the test's own client trusts the CA.
fn certificate(dir: &Path) -> (PathBuf, PathBuf, PathBuf) {
    let ca_key = rcgen::KeyPair::generate().unwrap();
    let mut ca_params = rcgen::CertificateParams::new(Vec::<String>::new()).unwrap();
    ca_params.is_ca = rcgen::IsCa::Ca(rcgen::BasicConstraints::Unconstrained);
    let ca = rcgen::CertifiedIssuer::self_signed(ca_params, ca_key).unwrap();
    let key = rcgen::KeyPair::generate().unwrap();
    let cert = rcgen::CertificateParams::new(vec!["127.0.0.1".to_string()])
        .unwrap()
        .signed_by(&key, &ca)
        .unwrap();
    let (a, c, k) = (
        dir.join("ca.pem"),
        dir.join("cert.pem"),
        dir.join("key.pem"),
    );
    std::fs::write(&a, ca.pem()).unwrap();
    std::fs::write(&c, cert.pem()).unwrap();
    std::fs::write(&k, key.serialize_pem()).unwrap();
    (a, c, k)
}

struct Cell {
    dir: tempfile::TempDir,
    port: u16,
    admin: String,
    viewer: String,
    ca: PathBuf,
    cert: PathBuf,
    key: PathBuf,
}

impl Cell {
    fn new() -> Cell {
        let dir = tempfile::tempdir().unwrap();
        let (ca, cert, key) = certificate(dir.path());
        Cell {
            ca,
            port: free_port(),
            admin: new_token().unwrap(),
            viewer: new_token().unwrap(),
            cert,
            key,
            dir,
        }
    }

    async fn start(&self) -> Daemon {
        let d = self.dir.path();
        let text = format!(
            "[daemon]\nstore = \"{}\"\nsocket = \"{}\"\n\n{}\n\
             [[access.token]]\nname = \"floor-viewer\"\nrole = \"viewer\"\nsha256 = \"{}\"\n",
            d.join("jobs.db").display(),
            d.join("ml.sock").display(),
            machines(),
            hex(&token_hash(&self.viewer))
        );
        let cfg = machlink::config::Config::parse(&text, &d.join("machlink.toml")).expect("config");
        Daemon::start(
            cfg,
            StartOptions {
                listen: Some(format!("127.0.0.1:{}", self.port)),
                token: Some(self.admin.clone()),
                tcp_security: TcpSecurity::Tls {
                    cert: self.cert.clone(),
                    key: self.key.clone(),
                },
                ..Default::default()
            },
        )
        .await
        .expect("the daemon starts with TLS")
    }

    /// A client of the TLS listener, with `token` or none.
    fn tls(&self, token: Option<&str>) -> Client {
        Client::new(Endpoint::Tls {
            addr: format!("127.0.0.1:{}", self.port),
            token: token.map(String::from),
            ca: self.ca.clone(),
            server_name: None,
        })
    }

    fn url(&self) -> String {
        format!("https://127.0.0.1:{}/", self.port)
    }
}

/// Waits until `script` (a function body returning a value) returns something truthy in the
/// page; that value. Fails naming `what` and the page's last answer.
async fn wait_page(s: &Session, what: &str, script: &str, args: Value, secs: u64) -> Value {
    let end = Instant::now() + Duration::from_secs(secs);
    let mut last = Value::Null;
    while Instant::now() < end {
        last = s.js(script, args.clone()).await;
        let truthy = match &last {
            Value::Null => false,
            Value::Bool(b) => *b,
            Value::String(t) => !t.is_empty(),
            Value::Array(a) => !a.is_empty(),
            _ => true,
        };
        if truthy {
            return last;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    panic!("the page never showed {what} within {secs} s (last answer: {last})");
}

const CARD_STATE: &str =
    "const c = document.querySelector(`article.machine[data-machine=\"${arguments[0]}\"]`); \
     return c ? c.querySelector('.state').textContent : null;";

/// The units the page shows done for job `id` (from its row in the jobs table).
const JOB_ACKED: &str = "const r = document.querySelector(`#jobs tr[data-job=\"${arguments[0]}\"] td:nth-child(5) span`); \
     return r ? Number(r.textContent.split(' / ')[0]) : -1;";

async fn login(s: &Session, url: &str, token: &str) {
    eprintln!("dashboard: log in at {url}");
    s.goto(url).await;
    wait_page(
        s,
        "the login form",
        "return !!document.getElementById('token');",
        json!([]),
        10,
    )
    .await;
    s.type_into("#token", token).await;
    s.click("#login-button").await;
    wait_page(
        s,
        "the live connection",
        "return document.getElementById('conn').dataset.conn === 'live';",
        json!([]),
        15,
    )
    .await;
}

fn target_dir() -> PathBuf {
    std::env::var_os("CARGO_TARGET_DIR")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../target"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_dashboard_in_chromium_shows_steers_and_survives_a_restart() {
    let missing: Vec<&str> = ["chromium", "chromedriver"]
        .into_iter()
        .filter(|p| find_program(p).is_none())
        .collect();
    assert!(
        missing.is_empty(),
        "the browser test needs {} on PATH (Debian: apt-get install chromium chromium-driver; .ci/run installs them)",
        missing.join(" and ")
    );
    let chromium = find_program("chromium").unwrap();
    let driver = Driver::start(&find_program("chromedriver").unwrap()).await;
    let cell = Cell::new();
    let d = cell.start().await;
    let admin = Client::new(Endpoint::Unix(d.socket.clone()));
    let profile = tempfile::tempdir().unwrap();
    let s = Session::new(&driver, &chromium, profile.path()).await;

    // the page loads over TLS, with nothing but its own files, and takes the token
    login(&s, &cell.url(), &cell.admin).await;
    let who = s
        .js(
            "return document.getElementById('who').textContent;",
            json!([]),
        )
        .await;
    assert_eq!(who, "command-line · admin");
    let stored = s
        .js(
            "return sessionStorage.getItem('machlink.token');",
            json!([]),
        )
        .await;
    assert_eq!(
        stored,
        cell.admin.as_str(),
        "the token lives in session storage"
    );
    let cookies = s.js("return document.cookie;", json!([])).await;
    assert_eq!(cookies, "", "the page sets no cookie");
    let foreign = s
        .js(
            "return performance.getEntriesByType('resource').map(e => e.name).filter(n => !n.startsWith(location.origin));",
            json!([]),
        )
        .await;
    assert_eq!(foreign, json!([]), "the page fetched from elsewhere");

    eprintln!("dashboard: four machines");
    // all four machines, each with its state
    let states = wait_page(
        &s,
        "four machines, three of them idle",
        "const a = Object.fromEntries([...document.querySelectorAll('article.machine')].map(c => [c.dataset.machine, c.dataset.state + ': ' + c.querySelector('.state').textContent])); \
         return Object.keys(a).length === 4 && ['router', 'press', 'sewer'].every(m => a[m] === 'idle: idle') ? a : null;",
        json!([]),
        20,
    )
    .await;
    // CANopen drives report only while a job runs: the page says so until one does
    assert_eq!(states["gantry"], "unknown: no report yet", "{states}");
    let square = "G21 G90\nG0 X0 Y0\nG1 X5 F900\nY5\nX0\nY0\n";
    let moved = admin
        .submit(&common::job("gantry", "square.nc", square))
        .await
        .unwrap();
    wait_until(&admin, moved.id, |j| j.state.is_final()).await;
    let gantry = wait_page(
        &s,
        "gantry's reported state",
        &format!("const t = (() => {{ {CARD_STATE} }})(); return t !== 'no report yet' && t;"),
        json!(["gantry"]),
        10,
    )
    .await;
    assert!(
        ["idle", "running"].contains(&gantry.as_str().unwrap()),
        "{gantry}"
    );

    eprintln!("dashboard: submit from the page");
    // a G-code job submitted from the page: preview, statistics, queue
    let lines = zigzag(900);
    let file = cell.dir.path().join("zigzag.nc");
    std::fs::write(&file, lines.join("\n")).unwrap();
    s.type_into("#sub-file", &file.display().to_string()).await;
    s.js(
        "const m = document.getElementById('sub-machine'); m.value = 'router'; \
         document.getElementById('sub-op').value = '';",
        json!([]),
    )
    .await;
    s.click("#sub-preview").await;
    let stats = wait_page(
        &s,
        "the plan's statistics",
        "return document.getElementById('sub-stats').textContent.includes('units for') && document.getElementById('sub-stats').textContent;",
        json!([]),
        20,
    )
    .await;
    let stats = stats.as_str().unwrap();
    assert!(
        stats.contains(&format!("{} units for router", lines.len())),
        "{stats}"
    );
    assert!(stats.contains("estimated time"), "{stats}");
    let on_router = || async {
        admin
            .jobs()
            .await
            .unwrap()
            .into_iter()
            .find(|j| j.machine == "router")
    };
    assert!(on_router().await.is_none(), "a preview queues nothing");
    s.click("#sub-queue").await;
    let mut queued = None;
    for _ in 0..200 {
        queued = on_router().await;
        if queued.is_some() {
            break;
        }
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    let Some(job) = queued else {
        let said = s
            .js("return document.getElementById('sub-error').textContent + ' | ' + document.getElementById('sub-stats').textContent;", json!([]))
            .await;
        panic!("the page queued no job: {said}");
    };
    assert_eq!(
        (job.machine.as_str(), job.total_units),
        ("router", lines.len())
    );
    let sim = d.device::<GrblSimHandle>("router").unwrap();

    eprintln!("dashboard: progress");
    // its progress on the page advances with what the simulator received and executed
    let mut seen = Vec::new();
    let mut last = 0i64;
    let end = Instant::now() + Duration::from_secs(30);
    while seen.len() < 3 && Instant::now() < end {
        let on_page = s.js(JOB_ACKED, json!([job.id])).await.as_i64().unwrap();
        let received = sim.received_lines() as i64;
        let executed = sim.trace().len();
        assert!(
            on_page <= received + 1,
            "the page shows {on_page} units done, the machine received {received} lines"
        );
        if on_page > last + 30 {
            seen.push((on_page, executed));
            last = on_page;
        }
        tokio::time::sleep(Duration::from_millis(150)).await;
    }
    assert!(
        seen.len() >= 3,
        "the page's progress did not advance: {seen:?}"
    );
    assert!(
        seen.windows(2).all(|w| w[1].1 > w[0].1),
        "the simulator's trace did not grow along: {seen:?}"
    );
    // the preview draws the executed part over the plan
    let done_len = s
        .js(
            "const g = document.querySelector('#preview g'); return g ? g.children[2].getAttribute('d').length : 0;",
            json!([]),
        )
        .await;
    assert!(done_len.as_u64().unwrap() > 0, "no executed part drawn");

    eprintln!("dashboard: pause");
    // Pause on the page: the simulated machine holds, and the page says so
    s.click("article.machine[data-machine=\"router\"] button[data-action=\"pause\"]")
        .await;
    wait_state(&admin, job.id, JobState::Paused).await;
    let held = wait_page(
        &s,
        "router held",
        "return document.querySelector('article.machine[data-machine=\"router\"]').dataset.state === 'held';",
        json!([]),
        10,
    )
    .await;
    assert_eq!(held, true);
    tokio::time::sleep(Duration::from_millis(300)).await;
    let (p0, t0) = (sim.position(), sim.trace().len());
    tokio::time::sleep(Duration::from_millis(700)).await;
    assert_eq!(
        (sim.position(), sim.trace().len()),
        (p0, t0),
        "the simulator moved while held"
    );
    assert!(
        (sim.received_lines() as usize) < lines.len(),
        "the job ended before the hold"
    );
    // the audit log names the page's pause as it names the CLI's: the token and the route
    let log = machlink::services::audit::read(d.access.audit.path()).unwrap();
    let pause = log
        .iter()
        .find(|r| r.action == format!("POST /jobs/{}/pause", job.id))
        .unwrap_or_else(|| panic!("no record of the page's pause in {log:#?}"));
    assert_eq!(
        (
            pause.token.as_deref(),
            pause.status,
            pause.outcome.as_str(),
            pause.machine.as_deref()
        ),
        (Some("command-line"), 200, "done", Some("router"))
    );
    assert!(pause.from.starts_with("tcp 127.0.0.1:"), "{pause:?}");

    eprintln!("dashboard: thread break");
    // a thread break on the sewing machine: "needs operator"
    let pocket = r#"{ "units": "mm", "paths": [ { "closed": true,
      "vertices": [[-30,-20,0],[30,-20,0],[30,20,0],[-30,20,0]] } ] }"#;
    let stitch = machlink::core::intake::JobSpec {
        operation: Some(machlink::core::intake::Operation::Stitch(
            offset_core::stitch::StitchParams {
                stitch_length: 2.5,
                ..Default::default()
            },
        )),
        ..common::job("sewer", "pocket.json", pocket)
    };
    let sewing = admin.submit(&stitch).await.unwrap();
    let needs = wait_page(
        &s,
        "sewer: needs operator",
        &format!(
            "const t = (() => {{ {CARD_STATE} }})(); return t && t.startsWith('needs operator') ? t : null;"
        ),
        json!(["sewer"]),
        30,
    )
    .await;
    assert_eq!(needs, "needs operator: thread break");
    let sewer = d.device::<SewingSim>("sewer").unwrap();
    assert!(sewer
        .trace
        .lock()
        .unwrap()
        .events
        .contains(&format!("thread break at {BREAK_AT}")));
    assert_eq!(admin.job(sewing.id).await.unwrap().state, JobState::Paused);

    eprintln!("dashboard: screenshots");
    // screenshots, landscape and portrait (kept by CI from target/dashboard/)
    let shots = target_dir().join("dashboard");
    std::fs::create_dir_all(&shots).unwrap();
    for (w, h) in [(1280, 800), (800, 1280)] {
        let png = s.screenshot(w, h).await;
        assert_eq!(&png[..8], b"\x89PNG\r\n\x1a\n");
        let at = shots.join(format!("dashboard-{w}x{h}.png"));
        std::fs::write(&at, &png).unwrap();
        eprintln!("wrote {}", at.display());
    }
    s.cmd(
        "POST",
        "/goog/cdp/execute",
        Some(json!({ "cmd": "Emulation.clearDeviceMetricsOverride", "params": {} })),
    )
    .await;

    eprintln!("dashboard: viewer");
    // a viewer: every action on the page is disabled, and a forged request is refused
    s.click("#logout").await;
    login(&s, &cell.url(), &cell.viewer).await;
    let actions = wait_page(
        &s,
        "the viewer's page with its machines and jobs",
        "const b = [...document.querySelectorAll('button[data-action]')]; \
         return document.querySelectorAll('article.machine').length === 4 && document.querySelectorAll('#jobs tbody tr').length >= 2 \
           ? b.map(x => [x.dataset.action, x.disabled]) : null;",
        json!([]),
        15,
    )
    .await;
    let actions = actions.as_array().unwrap();
    assert!(actions.len() >= 40, "{actions:?}");
    let enabled: Vec<_> = actions.iter().filter(|a| a[1] == false).collect();
    assert!(
        enabled.is_empty(),
        "a viewer's page has enabled actions: {enabled:?}"
    );
    let forged = s
        .js_async(
            "const done = arguments[arguments.length - 1]; \
             fetch(`/jobs/${arguments[0]}/cancel`, { method: 'POST', headers: { Authorization: 'Bearer ' + sessionStorage.getItem('machlink.token') } }) \
               .then(async r => done([r.status, (await r.json()).error]), e => done([0, String(e)]));",
            json!([job.id]),
        )
        .await;
    assert_eq!(forged[0], 403, "{forged}");
    assert!(
        forged[1].as_str().unwrap().contains("may only read"),
        "{forged}"
    );
    assert_eq!(admin.job(job.id).await.unwrap().state, JobState::Paused);
    let log = machlink::services::audit::read(d.access.audit.path()).unwrap();
    assert!(
        log.iter()
            .any(|r| r.token.as_deref() == Some("floor-viewer")
                && r.action == format!("POST /jobs/{}/cancel", job.id)
                && r.status == 403),
        "{log:#?}"
    );

    eprintln!("dashboard: restart");
    // the daemon restarts: the page finds it again by itself and follows the new one
    d.crash().await;
    wait_page(
        &s,
        "the lost connection",
        "return document.getElementById('conn').dataset.conn === 'retry';",
        json!([]),
        10,
    )
    .await;
    let d = cell.start().await;
    let admin = Client::new(Endpoint::Unix(d.socket.clone()));
    wait_page(
        &s,
        "the connection back",
        "return document.getElementById('conn').dataset.conn === 'live';",
        json!([]),
        20,
    )
    .await;
    // a job queued after the restart shows on the page from the new daemon's events
    let next = submit_gcode(&admin, "press", "after-restart", &zigzag(40)).await;
    let acked = wait_page(
        &s,
        "the job queued after the restart, done",
        "const r = document.querySelector(`#jobs tr[data-job=\"${arguments[0]}\"]`); \
         return r && r.dataset.jobState === 'completed' ? r.querySelector('td:nth-child(5) span').textContent : null;",
        json!([next.id]),
        30,
    )
    .await;
    assert_eq!(acked, format!("{0} / {0}", next.total_units));
    s.quit().await;
    drop(d);
}

/// Without a token only the page's own files are served (they hold no data); everything else
/// on TCP needs one. The page's whole size stays under the 300 KB docs/dashboard.md states.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn only_the_page_is_served_without_a_token_and_it_is_small() {
    use machlink::faces::dashboard::{PAGE, SCRIPT, STYLE};
    let cell = Cell::new();
    let _d = cell.start().await;
    let anon = cell.tls(None);
    for (path, body) in [
        ("/", PAGE),
        ("/dashboard/app.js", SCRIPT),
        ("/dashboard/style.css", STYLE),
    ] {
        let (st, got) = anon.raw(hyper::Method::GET, path, None).await.unwrap();
        assert_eq!(st.as_u16(), 200, "GET {path}");
        assert_eq!(got, body.as_bytes(), "GET {path}");
    }
    for path in [
        "/machines",
        "/jobs",
        "/events",
        "/metrics",
        "/whoami",
        "/jobs/1/path",
    ] {
        let (st, _) = anon.raw(hyper::Method::GET, path, None).await.unwrap();
        assert_eq!(st.as_u16(), 401, "GET {path} without a token");
    }
    let (st, _) = anon
        .raw(hyper::Method::POST, "/plan", Some(b"{}".to_vec()))
        .await
        .unwrap();
    assert_eq!(st.as_u16(), 401, "POST /plan without a token");
    let total = PAGE.len() + SCRIPT.len() + STYLE.len();
    assert!(total < 300 * 1024, "the page is {total} bytes");
    // the page refers to nothing outside the daemon
    for text in [PAGE, SCRIPT, STYLE] {
        let text = text.replace("http://www.w3.org/2000/svg", "");
        assert!(!text.contains("http://") && !text.contains("https://") && !text.contains("//cdn"));
    }
    // a viewer's token reads the page's drawing route, and may not plan
    let viewer = cell.tls(Some(&cell.viewer));
    let (st, b) = viewer
        .raw(
            hyper::Method::POST,
            "/plan",
            Some(serde_json::to_vec(&job("router", "a.nc", "G1 X1 F100\n")).unwrap()),
        )
        .await
        .unwrap();
    assert_eq!(st.as_u16(), 403, "{}", String::from_utf8_lossy(&b));
}
