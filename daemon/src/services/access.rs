//! Who may do what: roles, tokens, Unix peers, the route table, and the control lock per machine.
//!
//! Every caller becomes a [`Principal`]: a bearer token from the config's `[[access.token]]`
//! (stored as its SHA-256, compared in constant time), or on the Unix socket the peer's uid
//! and gid (SO_PEERCRED) looked up in `[[access.user]]` and `[[access.group]]`; the daemon's
//! own user is admin. Roles: `viewer` reads, `operator` steers the machines granted to it,
//! `admin` does everything (breaks locks, reloads the access table).
//!
//! Every route is one line of [`ROUTES`]: its method, path, what it needs and whether it takes
//! the machine's lock. A route missing from the table is refused for everyone (403), so a new
//! route cannot slip through unguarded: add its line here (see docs/security.md). The API's
//! gate (`faces::api::gate`) asks this module for each request; this module knows neither
//! the HTTP API nor the scheduler (whether a job is still open is asked of the caller).

use crate::core::store::{now_ms, JobId};
use crate::services::audit::Audit;
pub use crate::services::role::Role;
use axum::http::Method;
use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};
use std::collections::{BTreeMap, BTreeSet};
use std::net::SocketAddr;
use std::sync::{Mutex, RwLock};
use subtle::ConstantTimeEq;

/// The machines a grant covers.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Machines {
    /// Every machine (`machines` left out).
    All,
    Only(BTreeSet<String>),
}

impl Machines {
    pub fn covers(&self, machine: &str) -> bool {
        match self {
            Machines::All => true,
            Machines::Only(m) => m.contains(machine),
        }
    }
}

impl std::fmt::Display for Machines {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        match self {
            Machines::All => f.write_str("every machine"),
            Machines::Only(m) if m.is_empty() => f.write_str("no machine"),
            Machines::Only(m) => f.write_str(
                &m.iter()
                    .map(|n| format!("`{n}`"))
                    .collect::<Vec<_>>()
                    .join(", "),
            ),
        }
    }
}

/// A role over some machines.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Grant {
    pub role: Role,
    pub machines: Machines,
}

impl Grant {
    pub fn admin() -> Grant {
        Grant {
            role: Role::Admin,
            machines: Machines::All,
        }
    }
}

/// The shortest token the daemon takes; `machlink token new` makes 47-character ones.
pub const MIN_TOKEN_LEN: usize = 32;
/// What every token `machlink token new` makes starts with.
pub const TOKEN_PREFIX: &str = "mlk_";

/// A token the daemon knows: its name (shown in the audit log), its grant, and the SHA-256 of
/// the token (the token itself is never stored).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TokenEntry {
    pub name: String,
    pub grant: Grant,
    pub sha256: [u8; 32],
}

/// A new random token: `mlk_` and 43 characters of base64url (256 random bits).
pub fn new_token() -> Result<String, String> {
    let mut bytes = [0u8; 32];
    getrandom::fill(&mut bytes).map_err(|e| format!("cannot draw random bytes: {e}"))?;
    use base64::Engine;
    Ok(format!(
        "{TOKEN_PREFIX}{}",
        base64::engine::general_purpose::URL_SAFE_NO_PAD.encode(bytes)
    ))
}

/// The SHA-256 of a token, as the config stores it.
pub fn token_hash(token: &str) -> [u8; 32] {
    Sha256::digest(token.as_bytes()).into()
}

/// Lower-case hex.
pub fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

fn parse_hex32(s: &str) -> Option<[u8; 32]> {
    if s.len() != 64 || !s.is_ascii() {
        return None;
    }
    let mut out = [0u8; 32];
    for (i, o) in out.iter_mut().enumerate() {
        *o = u8::from_str_radix(&s[2 * i..2 * i + 2], 16).ok()?;
    }
    Some(out)
}

/// Checks a token given on the command line (`serve --token`): not empty, not short.
pub fn check_token_strength(token: &str) -> Result<(), String> {
    let n = token.chars().count();
    if n < MIN_TOKEN_LEN {
        return Err(format!(
            "the token is {n} characters long; a token must have at least {MIN_TOKEN_LEN} (`machlink token new` makes one)"
        ));
    }
    Ok(())
}

/// A local user or group the `[access]` table grants something.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct PeerRule {
    /// uid for a user rule, gid for a group rule.
    pub id: u32,
    /// How the config named it (`alice`, `uid 1001`).
    pub label: String,
    pub grant: Grant,
}

/// The `[access]` table, resolved.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct AccessConfig {
    pub tokens: Vec<TokenEntry>,
    pub users: Vec<PeerRule>,
    pub groups: Vec<PeerRule>,
    /// The group that may reach the socket: its folder is then 0750 and the socket 0660.
    pub socket_group: Option<(u32, String)>,
    /// Where the audit log goes (default: next to the store, `<store>-audit.jsonl`).
    pub audit_log: Option<std::path::PathBuf>,
}

/// The `[access]` table as written.
#[derive(Debug, Default, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RawAccess {
    #[serde(default)]
    socket_group: Option<String>,
    #[serde(default)]
    audit_log: Option<std::path::PathBuf>,
    #[serde(default)]
    token: Vec<RawToken>,
    #[serde(default)]
    user: Vec<RawPeer>,
    #[serde(default)]
    group: Vec<RawPeer>,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawToken {
    name: String,
    role: Role,
    #[serde(default)]
    machines: Option<Vec<String>>,
    sha256: String,
}

#[derive(Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct RawPeer {
    #[serde(default)]
    user: Option<String>,
    #[serde(default)]
    uid: Option<u32>,
    #[serde(default)]
    group: Option<String>,
    #[serde(default)]
    gid: Option<u32>,
    role: Role,
    #[serde(default)]
    machines: Option<Vec<String>>,
}

fn grant(
    role: Role,
    machines: Option<Vec<String>>,
    known: &[&str],
    who: &str,
) -> Result<Grant, String> {
    let machines = match machines {
        None => Machines::All,
        Some(_) if role == Role::Admin => {
            return Err(format!(
                "{who}: an admin holds every machine; leave out `machines`"
            ))
        }
        Some(list) => {
            for m in &list {
                if !known.contains(&m.as_str()) {
                    return Err(format!(
                        "{who}: machine `{m}` is not in this config (it has {})",
                        if known.is_empty() {
                            "no machines".to_string()
                        } else {
                            known.join(", ")
                        }
                    ));
                }
            }
            Machines::Only(list.into_iter().collect())
        }
    };
    Ok(Grant { role, machines })
}

impl RawAccess {
    /// Checks and resolves the table: names of users and groups looked up, token hashes
    /// read, machines checked against `machines`; `dir` anchors a relative audit log path.
    pub fn resolve(self, machines: &[&str], dir: &std::path::Path) -> Result<AccessConfig, String> {
        let mut cfg = AccessConfig {
            audit_log: self
                .audit_log
                .map(|p| if p.is_relative() { dir.join(p) } else { p }),
            ..Default::default()
        };
        if let Some(g) = self.socket_group {
            let gid = group_id(&g).ok_or_else(|| {
                format!("[access] socket_group: there is no group `{g}` on this system")
            })?;
            cfg.socket_group = Some((gid, g));
        }
        let mut names = BTreeSet::new();
        for t in self.token {
            let who = format!("[[access.token]] `{}`", t.name);
            if t.name.trim().is_empty() {
                return Err("[[access.token]]: `name` must not be empty".into());
            }
            if !names.insert(t.name.clone()) {
                return Err(format!("{who} is declared twice"));
            }
            let sha256 = parse_hex32(&t.sha256.to_ascii_lowercase()).ok_or_else(|| {
                format!("{who}: `sha256` must be 64 hex digits (what `machlink token new` prints)")
            })?;
            cfg.tokens.push(TokenEntry {
                grant: grant(t.role, t.machines, machines, &who)?,
                name: t.name,
                sha256,
            });
        }
        for u in self.user {
            if u.group.is_some() || u.gid.is_some() {
                return Err("[[access.user]] takes `user` or `uid`, not a group".into());
            }
            let (id, label) = match (u.user, u.uid) {
                (Some(name), None) => (
                    user_id(&name).ok_or_else(|| {
                        format!("[[access.user]]: there is no user `{name}` on this system")
                    })?,
                    name,
                ),
                (None, Some(uid)) => (uid, format!("uid {uid}")),
                _ => return Err("[[access.user]] takes one of `user` and `uid`".into()),
            };
            let who = format!("[[access.user]] `{label}`");
            cfg.users.push(PeerRule {
                id,
                grant: grant(u.role, u.machines, machines, &who)?,
                label,
            });
        }
        for g in self.group {
            if g.user.is_some() || g.uid.is_some() {
                return Err("[[access.group]] takes `group` or `gid`, not a user".into());
            }
            let (id, label) = match (g.group, g.gid) {
                (Some(name), None) => (
                    group_id(&name).ok_or_else(|| {
                        format!("[[access.group]]: there is no group `{name}` on this system")
                    })?,
                    name,
                ),
                (None, Some(gid)) => (gid, format!("gid {gid}")),
                _ => return Err("[[access.group]] takes one of `group` and `gid`".into()),
            };
            let who = format!("[[access.group]] `{label}`");
            cfg.groups.push(PeerRule {
                id,
                grant: grant(g.role, g.machines, machines, &who)?,
                label,
            });
        }
        Ok(cfg)
    }
}

fn user_id(name: &str) -> Option<u32> {
    nix::unistd::User::from_name(name)
        .ok()
        .flatten()
        .map(|u| u.uid.as_raw())
}

fn group_id(name: &str) -> Option<u32> {
    nix::unistd::Group::from_name(name)
        .ok()
        .flatten()
        .map(|g| g.gid.as_raw())
}

fn user_name(uid: u32) -> Option<String> {
    nix::unistd::User::from_uid(nix::unistd::Uid::from_raw(uid))
        .ok()
        .flatten()
        .map(|u| u.name)
}

/// The groups a user belongs to (primary and supplementary).
fn groups_of(uid: u32, gid: u32) -> Vec<u32> {
    let mut out = vec![gid];
    if let Some(u) = nix::unistd::User::from_uid(nix::unistd::Uid::from_raw(uid))
        .ok()
        .flatten()
    {
        if let Ok(name) = std::ffi::CString::new(u.name) {
            if let Ok(gs) = nix::unistd::getgrouplist(&name, nix::unistd::Gid::from_raw(gid)) {
                out.extend(gs.into_iter().map(|g| g.as_raw()));
            }
        }
    }
    out
}

/// Who is at the other end of a connection.
#[derive(Clone, Debug)]
pub enum Peer {
    /// A Unix-socket peer as the kernel reports it (SO_PEERCRED).
    Unix {
        uid: u32,
        gid: u32,
        pid: Option<i32>,
    },
    /// A Unix-socket peer whose credentials could not be read.
    UnixUnknown,
    /// A TCP peer (behind TLS, or plaintext when asked for).
    Tcp(SocketAddr),
}

impl Peer {
    /// From where, for the audit log.
    pub fn describe(&self) -> String {
        match self {
            Peer::Unix { uid, gid, pid } => format!(
                "unix socket, uid {uid} gid {gid}{}",
                pid.map(|p| format!(" pid {p}")).unwrap_or_default()
            ),
            Peer::UnixUnknown => "unix socket, unknown peer".into(),
            Peer::Tcp(a) => format!("tcp {a}"),
        }
    }
}

impl
    axum::extract::connect_info::Connected<
        axum::serve::IncomingStream<'_, tokio::net::UnixListener>,
    > for Peer
{
    fn connect_info(s: axum::serve::IncomingStream<'_, tokio::net::UnixListener>) -> Peer {
        match s.io().peer_cred() {
            Ok(c) => Peer::Unix {
                uid: c.uid(),
                gid: c.gid(),
                pid: c.pid(),
            },
            Err(_) => Peer::UnixUnknown,
        }
    }
}

impl
    axum::extract::connect_info::Connected<axum::serve::IncomingStream<'_, tokio::net::TcpListener>>
    for Peer
{
    fn connect_info(s: axum::serve::IncomingStream<'_, tokio::net::TcpListener>) -> Peer {
        Peer::Tcp(*s.remote_addr())
    }
}

/// A caller, authenticated: what it is called, what it may do, and from where it came.
#[derive(Clone, Debug, Serialize)]
pub struct Principal {
    /// The token's name, or the local user's name (`uid N` when it has none).
    pub name: String,
    /// The token's name when the caller came with a token.
    pub token: Option<String>,
    pub role: Role,
    pub machines: Machines,
    /// From where (socket peer or TCP address).
    pub from: String,
}

impl Principal {
    /// Whether it may steer machine `machine` (its role and its grant).
    pub fn may_operate(&self, machine: &str) -> bool {
        self.role == Role::Admin || (self.role >= Role::Operator && self.machines.covers(machine))
    }

    pub fn describe(&self) -> String {
        match self.role {
            Role::Admin => format!("`{}` (admin)", self.name),
            r => format!("`{}` ({r} on {})", self.name, self.machines),
        }
    }
}

/// What a route needs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Need {
    /// Any role.
    Read,
    /// Operator (or admin) on the machine the route acts on, which must not be locked by
    /// someone else.
    Operate(Scope),
    /// Admin only.
    Admin,
    /// Anyone, without a token: the dashboard's own files (`faces::dashboard`), which hold no
    /// data.
    Page,
}

/// Which machine an operating route acts on.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Scope {
    /// The machine of the job in the path's `{id}`.
    Job,
    /// The machine in the path's `{name}`.
    Machine,
    /// The machine named in the request body: the handler checks it with
    /// [`Access::check_operate`] before acting.
    Body,
}

/// One line of the route table.
#[derive(Clone, Copy, Debug)]
pub struct Route {
    pub method: &'static str,
    pub path: &'static str,
    pub need: Need,
    /// A success takes the machine's control lock for the caller (until its jobs there end).
    pub takes_lock: bool,
}

const fn route(method: &'static str, path: &'static str, need: Need, takes_lock: bool) -> Route {
    Route {
        method,
        path,
        need,
        takes_lock,
    }
}

/// Every API route and what it needs. A new route joins with one line here; a route missing
/// from this table is refused for every caller.
pub const ROUTES: &[Route] = &[
    route("GET", "/machines", Need::Read, false),
    route("GET", "/jobs", Need::Read, false),
    route("GET", "/jobs/{id}", Need::Read, false),
    route("GET", "/jobs/{id}/events", Need::Read, false),
    route("GET", "/locks", Need::Read, false),
    route("GET", "/whoami", Need::Read, false),
    route("GET", "/metrics", Need::Read, false),
    route("GET", "/events", Need::Read, false),
    route("GET", "/jobs/{id}/resume", Need::Read, false),
    route("POST", "/jobs", Need::Operate(Scope::Body), true),
    route(
        "POST",
        "/machines/{name}/gcode",
        Need::Operate(Scope::Machine),
        true,
    ),
    route("POST", "/jobs/{id}/pause", Need::Operate(Scope::Job), false),
    route("POST", "/jobs/{id}/resume", Need::Operate(Scope::Job), true),
    route(
        "POST",
        "/jobs/{id}/cancel",
        Need::Operate(Scope::Job),
        false,
    ),
    route(
        "POST",
        "/machines/{name}/lock",
        Need::Operate(Scope::Machine),
        false,
    ),
    route(
        "POST",
        "/machines/{name}/release",
        Need::Operate(Scope::Machine),
        false,
    ),
    route(
        "POST",
        "/jobs/{id}/override",
        Need::Operate(Scope::Job),
        false,
    ),
    // unlock, home and jog: between jobs, on a machine nobody else holds
    route(
        "POST",
        "/machines/{name}/{op}",
        Need::Operate(Scope::Machine),
        false,
    ),
    route("POST", "/access/reload", Need::Admin, false),
    // the dashboard (`faces::dashboard`): its files, and what it draws and plans before a submit
    route("GET", "/", Need::Page, false),
    route("GET", "/dashboard/app.js", Need::Page, false),
    route("GET", "/dashboard/style.css", Need::Page, false),
    route("GET", "/jobs/{id}/path", Need::Read, false),
    route("POST", "/plan", Need::Operate(Scope::Body), false),
];

/// The route table's line for a request, if any.
pub fn route_of(method: &Method, path: &str) -> Option<&'static Route> {
    ROUTES
        .iter()
        .find(|r| r.method == method.as_str() && r.path == path)
}

/// A machine's control lock: one operator at a time.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct LockInfo {
    pub machine: String,
    /// Who holds it (a token's name or a local user's).
    pub holder: String,
    /// Taken with `machlink lock` (held until released), or by a submit (held until the
    /// holder's jobs on the machine end).
    pub explicit: bool,
    pub since_ms: i64,
    /// The holder's jobs that keep an implicit lock.
    pub jobs: Vec<JobId>,
}

/// What a handler tells the access layer about what it did (for the lock and the audit log).
#[derive(Clone, Debug, Default)]
pub struct Acted {
    pub machine: Option<String>,
    pub job: Option<JobId>,
    /// A note for the audit log (a lock broken, …).
    pub note: Option<String>,
}

/// Access control shared by the API's handlers.
pub struct Access {
    config: RwLock<AccessConfig>,
    /// Tokens from the command line (`serve --token`): admin.
    extra_tokens: Vec<TokenEntry>,
    owner_uid: u32,
    locks: Mutex<BTreeMap<String, LockInfo>>,
    pub audit: Audit,
    /// The config file, for `POST /access/reload`.
    pub config_path: Option<std::path::PathBuf>,
}

/// A refusal of the access layer, as one sentence; the API answers each kind with its own
/// status (`faces::api::error`).
#[derive(Debug, thiserror::Error)]
pub enum AccessError {
    /// No token where one is needed, or one the daemon does not know.
    #[error("{0}")]
    Unauthenticated(String),
    /// The caller is known but may not do this (its role, its machines, the route table).
    #[error("{0}")]
    Forbidden(String),
    /// Someone else holds the machine's control lock.
    #[error("{0}")]
    Locked(String),
}

impl Access {
    pub fn new(
        config: AccessConfig,
        cli_token: Option<String>,
        audit: Audit,
        config_path: Option<std::path::PathBuf>,
    ) -> Access {
        let extra_tokens = cli_token
            .map(|t| TokenEntry {
                name: "command-line".into(),
                grant: Grant::admin(),
                sha256: token_hash(&t),
            })
            .into_iter()
            .collect();
        Access {
            config: RwLock::new(config),
            extra_tokens,
            owner_uid: nix::unistd::geteuid().as_raw(),
            locks: Mutex::new(BTreeMap::new()),
            audit,
            config_path,
        }
    }

    /// Whether any token can reach the daemon (TCP needs one).
    pub fn has_tokens(&self) -> bool {
        !self.extra_tokens.is_empty() || !read(&self.config).tokens.is_empty()
    }

    /// Replaces the tokens, users and groups (the socket group and audit log stay as the
    /// daemon started with them).
    pub fn reload(&self, new: AccessConfig) {
        let mut c = write(&self.config);
        let (group, audit) = (c.socket_group.clone(), c.audit_log.clone());
        *c = AccessConfig {
            socket_group: group,
            audit_log: audit,
            ..new
        };
    }

    /// The token's entry; every known token is compared, in constant time, whatever matches.
    fn token(&self, given: &str) -> Option<TokenEntry> {
        let h = token_hash(given);
        let cfg = read(&self.config);
        let mut found = None;
        for t in cfg.tokens.iter().chain(&self.extra_tokens) {
            if bool::from(t.sha256.ct_eq(&h)) && found.is_none() {
                found = Some(t.clone());
            }
        }
        found
    }

    /// Who a request comes from: its bearer token if it has one, else (on the Unix socket)
    /// its peer's uid and gid. TCP requests must carry a token.
    pub fn authenticate(
        &self,
        peer: &Peer,
        bearer: Option<&str>,
    ) -> Result<Principal, AccessError> {
        let from = peer.describe();
        if let Some(given) = bearer {
            if given.chars().count() < MIN_TOKEN_LEN {
                return Err(AccessError::Unauthenticated(
                    "the bearer token is too short to be one of this daemon's".into(),
                ));
            }
            return match self.token(given) {
                Some(t) => Ok(Principal {
                    name: t.name.clone(),
                    token: Some(t.name),
                    role: t.grant.role,
                    machines: t.grant.machines,
                    from,
                }),
                None => Err(AccessError::Unauthenticated(
                    "this daemon knows no such token (check `Authorization: Bearer TOKEN`)".into(),
                )),
            };
        }
        match peer {
            Peer::Tcp(_) => Err(AccessError::Unauthenticated("this daemon needs `Authorization: Bearer TOKEN` on TCP (a token from its config's [[access.token]] or serve --token)".into(),
            )),
            Peer::UnixUnknown => Err(AccessError::Forbidden("the daemon cannot tell who is at the other end of the socket".into(),
            )),
            Peer::Unix { uid, gid, .. } => {
                let name = user_name(*uid).unwrap_or_else(|| format!("uid {uid}"));
                let grant = self.peer_grant(*uid, *gid).ok_or_else(|| {
                    AccessError::Forbidden(format!(
                            "{name} (uid {uid}) has no role on this daemon: add it to the config's [[access.user]] or [[access.group]]"
                        ),
                    )
                })?;
                Ok(Principal {
                    name,
                    token: None,
                    role: grant.role,
                    machines: grant.machines,
                    from,
                })
            }
        }
    }

    /// The grant of a local user: the daemon's own user is admin; else its `[[access.user]]`;
    /// else the first `[[access.group]]` it belongs to.
    fn peer_grant(&self, uid: u32, gid: u32) -> Option<Grant> {
        if uid == self.owner_uid {
            return Some(Grant::admin());
        }
        let cfg = read(&self.config);
        if let Some(u) = cfg.users.iter().find(|u| u.id == uid) {
            return Some(u.grant.clone());
        }
        if cfg.groups.is_empty() {
            return None;
        }
        let groups = groups_of(uid, gid);
        cfg.groups
            .iter()
            .find(|g| groups.contains(&g.id))
            .map(|g| g.grant.clone())
    }

    /// Whether `p` may steer machine `machine` now: its grant, and nobody else's lock.
    /// Admins pass locks (they can break them).
    pub fn check_operate(
        &self,
        p: &Principal,
        machine: &str,
        open: &dyn Fn(JobId) -> bool,
    ) -> Result<(), AccessError> {
        if !p.may_operate(machine) {
            return Err(AccessError::Forbidden(format!(
                "{} may not act on machine `{machine}`",
                p.describe()
            )));
        }
        if p.role == Role::Admin {
            return Ok(());
        }
        if let Some(l) = self.holder(machine, open) {
            if l.holder != p.name {
                return Err(AccessError::Locked(format!(
                        "machine `{machine}` is locked by `{}`; ask them to release it (machlink release {machine}), or an admin can break the lock",
                        l.holder
                    ),
                ));
            }
        }
        Ok(())
    }

    /// The machine's lock, if it is held (an implicit lock whose jobs all ended is let go).
    pub fn holder(&self, machine: &str, open: &dyn Fn(JobId) -> bool) -> Option<LockInfo> {
        let mut locks = lock(&self.locks);
        let l = locks.get(machine)?;
        if !l.explicit && !l.jobs.iter().any(|&j| open(j)) {
            locks.remove(machine);
            return None;
        }
        locks.get(machine).cloned()
    }

    /// Every lock held now.
    pub fn locks(&self, open: &dyn Fn(JobId) -> bool) -> Vec<LockInfo> {
        let names: Vec<String> = lock(&self.locks).keys().cloned().collect();
        names.iter().filter_map(|m| self.holder(m, open)).collect()
    }

    /// Takes the lock of `machine` for `p` (explicitly, with `machlink lock`); with `take_over`
    /// (admins), from whoever holds it. Returns whom it was taken from.
    pub fn take(
        &self,
        p: &Principal,
        machine: &str,
        take_over: bool,
        open: &dyn Fn(JobId) -> bool,
    ) -> Result<Option<String>, AccessError> {
        let held = self.holder(machine, open);
        let mut locks = lock(&self.locks);
        match held {
            Some(l) if l.holder != p.name && !take_over => Err(AccessError::Locked(format!(
                    "machine `{machine}` is locked by `{}`; an admin can take it over with `machlink lock {machine} --break`",
                    l.holder
                ),
            )),
            Some(l) if l.holder == p.name => {
                if let Some(mine) = locks.get_mut(machine) {
                    mine.explicit = true;
                }
                Ok(None)
            }
            held => {
                locks.insert(
                    machine.to_string(),
                    LockInfo {
                        machine: machine.to_string(),
                        holder: p.name.clone(),
                        explicit: true,
                        since_ms: now_ms(),
                        jobs: Vec::new(),
                    },
                );
                Ok(held.map(|l| l.holder))
            }
        }
    }

    /// Lets go of the lock of `machine`: its holder, or an admin (breaking it). Returns whom
    /// it was released from.
    pub fn release(
        &self,
        p: &Principal,
        machine: &str,
        open: &dyn Fn(JobId) -> bool,
    ) -> Result<Option<String>, AccessError> {
        let held = self.holder(machine, open);
        match held {
            None => Ok(None),
            Some(l) if l.holder == p.name || p.role == Role::Admin => {
                lock(&self.locks).remove(machine);
                Ok(Some(l.holder))
            }
            Some(l) => Err(AccessError::Locked(format!(
                    "machine `{machine}` is locked by `{}`, not by `{}`; only they or an admin can release it",
                    l.holder, p.name
                ),
            )),
        }
    }

    /// A job `p` submitted or resumed on `machine`: the lock is taken (or kept) for it until
    /// the job ends. An admin acting on a machine someone else holds leaves the lock alone.
    pub fn note_job(
        &self,
        p: &Principal,
        machine: &str,
        job: Option<JobId>,
        open: &dyn Fn(JobId) -> bool,
    ) {
        let held = self.holder(machine, open);
        let mut locks = lock(&self.locks);
        match held {
            Some(l) if l.holder != p.name => {}
            Some(_) => {
                if let (Some(l), Some(j)) = (locks.get_mut(machine), job) {
                    if !l.jobs.contains(&j) {
                        l.jobs.push(j);
                    }
                }
            }
            None => {
                locks.insert(
                    machine.to_string(),
                    LockInfo {
                        machine: machine.to_string(),
                        holder: p.name.clone(),
                        explicit: false,
                        since_ms: now_ms(),
                        jobs: job.into_iter().collect(),
                    },
                );
            }
        }
    }
}

fn lock<T>(m: &Mutex<T>) -> std::sync::MutexGuard<'_, T> {
    m.lock().unwrap_or_else(|p| p.into_inner())
}
fn read<T>(m: &RwLock<T>) -> std::sync::RwLockReadGuard<'_, T> {
    m.read().unwrap_or_else(|p| p.into_inner())
}
fn write<T>(m: &RwLock<T>) -> std::sync::RwLockWriteGuard<'_, T> {
    m.write().unwrap_or_else(|p| p.into_inner())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tokens_are_random_long_and_hashed() {
        let a = new_token().unwrap();
        let b = new_token().unwrap();
        assert_ne!(a, b);
        assert!(a.starts_with(TOKEN_PREFIX) && a.len() == 47, "{a}");
        assert!(check_token_strength(&a).is_ok());
        assert!(check_token_strength("").is_err());
        assert!(check_token_strength("s3cret").is_err());
        let h = hex(&token_hash("abc"));
        assert_eq!(
            h,
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        assert_eq!(parse_hex32(&h), Some(token_hash("abc")));
    }

    #[test]
    fn every_route_is_in_the_table_once() {
        let mut seen = BTreeSet::new();
        for r in ROUTES {
            assert!(
                seen.insert((r.method, r.path)),
                "{} {} twice",
                r.method,
                r.path
            );
        }
    }

    #[test]
    fn socket_peers_get_the_role_of_their_uid_or_group() {
        let viewer = Grant {
            role: Role::Viewer,
            machines: Machines::All,
        };
        let operator = Grant {
            role: Role::Operator,
            machines: Machines::Only(["router".to_string()].into()),
        };
        let cfg = AccessConfig {
            users: vec![PeerRule {
                id: 64001,
                label: "uid 64001".into(),
                grant: operator.clone(),
            }],
            groups: vec![PeerRule {
                id: 64100,
                label: "gid 64100".into(),
                grant: viewer,
            }],
            ..Default::default()
        };
        let a = Access::new(cfg, None, Audit::none(), None);
        let unix = |uid, gid| Peer::Unix {
            uid,
            gid,
            pid: Some(7),
        };
        let me = nix::unistd::geteuid().as_raw();
        let owner = a.authenticate(&unix(me, 0), None).unwrap();
        assert_eq!(owner.role, Role::Admin);
        let op = a.authenticate(&unix(64001, 64001), None).unwrap();
        assert_eq!(
            (op.role, op.may_operate("router"), op.may_operate("mill")),
            (Role::Operator, true, false)
        );
        assert_eq!(op.from, "unix socket, uid 64001 gid 64001 pid 7");
        let v = a.authenticate(&unix(64002, 64100), None).unwrap();
        assert_eq!(v.role, Role::Viewer);
        let e = a.authenticate(&unix(64003, 64003), None).unwrap_err();
        assert!(matches!(e, AccessError::Forbidden(_)), "{e:?}");
        assert!(e.to_string().contains("has no role on this daemon"), "{e}");
        // a token on the socket decides over the peer
        let e = a
            .authenticate(&unix(me, 0), Some("not-a-token-but-long-enough-to-look-up"))
            .unwrap_err();
        assert!(matches!(e, AccessError::Unauthenticated(_)), "{e:?}");
        // TCP without a token: refused
        let e = a
            .authenticate(&Peer::Tcp("127.0.0.1:9".parse().unwrap()), None)
            .unwrap_err();
        assert!(matches!(e, AccessError::Unauthenticated(_)), "{e:?}");
    }

    #[test]
    fn the_access_table_names_its_mistakes() {
        let raw: RawAccess = toml::from_str(
            "[[token]]\nname = \"t\"\nrole = \"operator\"\nmachines = [\"nope\"]\nsha256 = \"00\"\n",
        )
        .unwrap();
        let e = raw
            .resolve(&["router"], std::path::Path::new("/"))
            .unwrap_err();
        assert!(e.contains("64 hex digits"), "{e}");
        let raw: RawAccess = toml::from_str(&format!(
            "[[token]]\nname = \"t\"\nrole = \"operator\"\nmachines = [\"nope\"]\nsha256 = \"{}\"\n",
            hex(&token_hash("x"))
        ))
        .unwrap();
        let e = raw
            .resolve(&["router"], std::path::Path::new("/"))
            .unwrap_err();
        assert!(e.contains("machine `nope` is not in this config"), "{e}");
        let raw: RawAccess =
            toml::from_str("[[user]]\nuid = 4242\nrole = \"admin\"\nmachines = [\"router\"]\n")
                .unwrap();
        let e = raw
            .resolve(&["router"], std::path::Path::new("/"))
            .unwrap_err();
        assert!(e.contains("an admin holds every machine"), "{e}");
    }
}
