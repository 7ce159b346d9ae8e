//! `machlink dashboard` through the binary: on the Unix socket it serves a loopback proxy
//! whose printed URL carries a one-time key; the page's files need none, every API request
//! needs the key and reaches the daemon as the caller's own; a daemon reached on TCP gets its
//! own URL printed.

use crate::common;

use common::cli::{machlink, run, stderr};
use machlink::faces::client::{Client, Endpoint};
use std::io::{BufRead, BufReader};

struct Child(std::process::Child);
impl Drop for Child {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_dashboard_proxy_serves_the_page_and_passes_only_keyed_requests() {
    let dir = tempfile::tempdir().unwrap();
    let socket = dir.path().join("ml.sock");
    let cfg = machlink::config::Config::parse(
        &format!(
            "[daemon]\nstore = \"{}\"\nsocket = \"{}\"\n\n[[machine]]\nname = \"bench\"\nlink = \"sim-grbl\"\ntime_scale = 100.0\n",
            dir.path().join("jobs.db").display(),
            socket.display()
        ),
        &dir.path().join("machlink.toml"),
    )
    .unwrap();
    let _d = machlink::daemon::Daemon::start(cfg, Default::default())
        .await
        .unwrap();
    let mut child = Child(
        machlink()
            .args(["dashboard", "--socket"])
            .arg(&socket)
            .stdout(std::process::Stdio::piped())
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap(),
    );
    let mut url = String::new();
    BufReader::new(child.0.stdout.take().unwrap())
        .read_line(&mut url)
        .unwrap();
    let url = url.trim();
    let rest = url
        .strip_prefix("http://")
        .unwrap_or_else(|| panic!("not a URL: {url:?}"));
    let (addr, key) = rest.split_once("/#token=").unwrap();
    assert!(addr.starts_with("127.0.0.1:"), "{url}");
    let through = |token: Option<&str>| {
        Client::new(Endpoint::Tcp {
            addr: addr.to_string(),
            token: token.map(String::from),
        })
    };
    // the page, with no key
    let (st, page) = through(None)
        .raw(hyper::Method::GET, "/", None)
        .await
        .unwrap();
    assert_eq!(st.as_u16(), 200);
    assert_eq!(page, machlink::faces::dashboard::PAGE.as_bytes());
    // the API: with the key, as the daemon's own user (admin); without it or with another, refused
    let who = through(Some(key)).whoami().await.unwrap();
    assert_eq!(who["role"], "admin", "{who}");
    assert!(
        who["from"].as_str().unwrap().starts_with("unix socket"),
        "{who}"
    );
    assert_eq!(
        through(Some(key)).machines().await.unwrap()[0].name,
        "bench"
    );
    for wrong in [None, Some(machlink::services::access::new_token().unwrap())] {
        let (st, body) = through(wrong.as_deref())
            .raw(hyper::Method::GET, "/machines", None)
            .await
            .unwrap();
        assert_eq!(st.as_u16(), 401, "{}", String::from_utf8_lossy(&body));
    }
}

#[test]
fn a_daemon_on_tcp_gets_its_own_url_and_no_daemon_is_one_sentence() {
    let o = run(&[
        "dashboard",
        "--connect",
        "cell-3:7878",
        "--ca",
        "/etc/machlink/ca.pem",
    ]);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(String::from_utf8_lossy(&o.stdout), "https://cell-3:7878/\n");
    let dir = tempfile::tempdir().unwrap();
    let none = dir.path().join("none.sock");
    let o = run(&[
        std::ffi::OsStr::new("dashboard"),
        std::ffi::OsStr::new("--socket"),
        none.as_os_str(),
    ]);
    assert!(!o.status.success());
    let e = stderr(&o);
    assert!(e.contains("no daemon answers on"), "{e}");
}
