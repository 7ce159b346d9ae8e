//! `machlink check-config FILE`: reads a config offline as `serve` would and reports every
//! mistake (file, line, key), each machine table checked on its own so one mistake does not
//! hide the next, and warns of a serial port that does not exist.

use machlink::config::Config;
use std::path::{Path, PathBuf};

#[derive(clap::Args)]
pub struct CheckConfigArgs {
    /// The configuration file to check.
    pub file: PathBuf,
}

/// A section of the file: the `[[machine]]` table it belongs to (None: the other tables).
struct Section {
    machine: Option<usize>,
    lines: std::ops::Range<usize>,
}

/// Splits the file at its table headers: each `[[machine]]` with its sub-tables is one
/// section, everything else (`[daemon]`, `[fleet]`, `[[webhook]]`, …) the rest.
fn sections(text: &str) -> Vec<Section> {
    let mut out: Vec<Section> = Vec::new();
    let mut machines = 0;
    for (i, line) in text.lines().enumerate() {
        let t = line.trim_start();
        let header = t
            .strip_prefix("[[")
            .map(|r| (true, r))
            .or_else(|| t.strip_prefix('[').map(|r| (false, r)));
        let owner = match header {
            Some((array, rest)) => {
                let name = rest.split(']').next().unwrap_or("").trim();
                if array && name == "machine" {
                    machines += 1;
                    Some(Some(machines - 1))
                } else if name.starts_with("machine.") {
                    out.last().map(|s| s.machine)
                } else {
                    Some(None)
                }
            }
            None => None,
        };
        match (owner, out.last_mut()) {
            (Some(m), _) => out.push(Section {
                machine: m,
                lines: i..i + 1,
            }),
            (None, Some(s)) => s.lines.end = i + 1,
            (None, None) => out.push(Section {
                machine: None,
                lines: i..i + 1,
            }),
        }
    }
    out
}

/// The text with only the lines `keep` says yes to; every other byte but line ends is a
/// space, so lines and columns stay where they were.
fn only(text: &str, keep: impl Fn(usize) -> bool) -> String {
    text.split_inclusive('\n')
        .enumerate()
        .map(|(i, l)| {
            if keep(i) {
                l.to_string()
            } else {
                l.bytes()
                    .map(|b| {
                        if b == b'\n' || b == b'\r' {
                            b as char
                        } else {
                            ' '
                        }
                    })
                    .collect()
            }
        })
        .collect()
}

/// Every mistake in the file, one sentence each, in the order of their lines.
pub fn errors(text: &str, path: &Path) -> Vec<String> {
    let Err(first) = Config::parse(text, path) else {
        return Vec::new();
    };
    if toml::from_str::<toml::Table>(text).is_err() {
        // not TOML at all: nothing after the first mistake can be read
        return vec![first.to_string()];
    }
    let secs = sections(text);
    let section_of = |i: usize| secs.iter().position(|s| s.lines.contains(&i));
    let mut found: Vec<(usize, String)> = Vec::new();
    // each machine table alone
    let mut machines: Vec<usize> = secs.iter().filter_map(|s| s.machine).collect();
    machines.dedup();
    let mut broken = Vec::new();
    for m in machines {
        let part = only(text, |i| {
            section_of(i).is_some_and(|s| secs[s].machine == Some(m))
        });
        if let Err(e) = Config::parse(&part, path) {
            found.push((line(&e), e.to_string()));
            broken.push(m);
        }
    }
    // each of the other tables alone, with the machines that read (a fleet names them)
    let others: Vec<usize> = (0..secs.len())
        .filter(|&k| secs[k].machine.is_none())
        .collect();
    for &k in &others {
        let part = only(text, |i| {
            section_of(i)
                .is_some_and(|s| s == k || secs[s].machine.is_some_and(|m| !broken.contains(&m)))
        });
        if let Err(e) = Config::parse(&part, path) {
            found.push((line(&e), e.to_string()));
        }
    }
    // a name given twice, whether or not either table reads
    found.extend(twice_named(text, path, &secs));
    if !found.iter().any(|(_, m)| *m == first.to_string()) {
        found.push((line(&first), first.to_string()));
    }
    // the duplicate said once, with both lines
    if found.iter().any(|(_, m)| m.contains("(first at line")) {
        found.retain(|(_, m)| !m.contains("is declared twice") || m.contains("(first at line"));
    }
    found.sort();
    found.dedup();
    found.into_iter().map(|(_, m)| m).collect()
}

/// Machine names declared more than once, each at the line of its second table.
fn twice_named(text: &str, path: &Path, secs: &[Section]) -> Vec<(usize, String)> {
    let lines: Vec<&str> = text.lines().collect();
    let mut seen: Vec<(String, usize)> = Vec::new();
    let mut out = Vec::new();
    let mut done: Vec<usize> = Vec::new();
    for s in secs {
        let Some(m) = s.machine else { continue };
        if done.contains(&m) {
            continue;
        }
        let named = s.lines.clone().find_map(|l| {
            let (k, v) = lines[l].split_once('=')?;
            (k.trim() == "name").then(|| (l, v.trim().trim_matches('"').to_string()))
        });
        let Some((l, name)) = named else { continue };
        done.push(m);
        match seen.iter().find(|(n, _)| *n == name) {
            Some((_, first)) => out.push((
                l + 1,
                format!(
                    "{}, line {}: machine `{name}` is declared twice (first at line {}); each machine needs its own name",
                    path.display(),
                    l + 1,
                    first + 1
                ),
            )),
            None => seen.push((name, l)),
        }
    }
    out
}

fn line(e: &machlink::config::ConfigError) -> usize {
    match e {
        machlink::config::ConfigError::Invalid { line, .. } => *line,
        _ => 0,
    }
}

/// Warnings for a config that reads: serial ports (a machine's `port` that is a path)
/// that do not exist now.
pub fn warnings(text: &str, path: &Path, config: &Config) -> Vec<String> {
    let secs = sections(text);
    let lines: Vec<&str> = text.lines().collect();
    let mut out = Vec::new();
    for (i, m) in config.machines.iter().enumerate() {
        let Some(port) = m.settings.json.get("port").and_then(|p| p.as_str()) else {
            continue;
        };
        if !port.starts_with('/') || Path::new(port).exists() {
            continue;
        }
        let line = secs
            .iter()
            .filter(|s| s.machine == Some(i))
            .flat_map(|s| s.lines.clone())
            .find(|&l| {
                let t = lines[l].trim_start();
                t.strip_prefix("port")
                    .is_some_and(|r| r.trim_start().starts_with('='))
            })
            .map(|l| format!(", line {}", l + 1))
            .unwrap_or_default();
        out.push(format!(
            "{}{line}: machine `{}`: key `port`: the serial port {port} does not exist (now); its jobs fail until it does",
            path.display(),
            m.name
        ));
    }
    out
}

pub fn run(a: CheckConfigArgs) -> anyhow::Result<()> {
    let text = std::fs::read_to_string(&a.file)
        .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", a.file.display()))?;
    let errs = errors(&text, &a.file);
    if let Some((last, rest)) = errs.split_last() {
        for e in rest {
            eprintln!("machlink: {e}");
        }
        anyhow::bail!("{last}");
    }
    let config = Config::parse(&text, &a.file)?;
    for w in warnings(&text, &a.file, &config) {
        eprintln!("machlink: warning: {w}");
    }
    println!(
        "{}: ok ({} machine{})",
        a.file.display(),
        config.machines.len(),
        if config.machines.len() == 1 { "" } else { "s" }
    );
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn five_independent_mistakes_are_all_reported_in_one_run() {
        let text = "[daemon]\njournal_every = \"often\"\n\n\
                    [[machine]]\nname = \"router\"\nlink = \"sim-grbl\"\nmax_feed = \"fast\"\n\n\
                    [[machine]]\nname = \"router\"\nlink = \"sim-grbl\"\n\n\
                    [[webhook]]\nurl = \"http://127.0.0.1:9/hook\"\nevents = [\"completed\", \"exploded\"]\n\n\
                    [fleet]\nurl = \"nats://127.0.0.1:4222\"\n";
        let e = errors(text, Path::new("cell.toml"));
        let all = e.join("\n");
        assert_eq!(e.len(), 5, "{all}");
        for (what, said) in [
            ("journal_every", "must be a whole number, not \"often\""),
            ("max_feed", "must be a number of mm/min, not \"fast\""),
            ("duplicate", "machine `router` is declared twice"),
            ("webhook event", "exploded"),
            ("fleet name", "[fleet]"),
        ] {
            assert!(all.contains(said), "{what} not reported: {all}");
        }
    }

    #[test]
    fn every_machine_table_is_checked_on_its_own() {
        let text = "[daemon]\njournal_every = 5\n\n[[machine]]\nname = \"a\"\nlink = \"grbl\"\nprot = \"/dev/x\"\n\n[[machine]]\nname = \"b\"\nlink = \"sim-grbl\"\ntime_scale = \"fast\"\n";
        let e = errors(text, Path::new("cell.toml"));
        assert_eq!(e.len(), 2, "{e:#?}");
        assert!(e[0].contains("line 7") && e[0].contains("`prot`"), "{e:#?}");
        assert!(
            e[1].contains("line 12") && e[1].contains("`time_scale`"),
            "{e:#?}"
        );
    }
}
