//! `machlink-sim canopen`: simulated CiA 402 drives behind an SLCAN adapter on a pty.

use super::{spawn_adapter, DriveFault, SimDrives};
use anyhow::Context;
use clap::Args;
use machlink_protocols::canopen::MemoryBus;
use std::path::PathBuf;

/// The command line of `machlink-sim canopen`.
#[derive(Args, Debug)]
pub struct CanopenArgs {
    /// Make this path a symbolic link to the adapter's pty (an existing link is replaced).
    #[arg(long)]
    pub slcan_pty: PathBuf,
    /// The drives' node ids, e.g. 1,2,3.
    #[arg(long, value_delimiter = ',', default_value = "1,2,3")]
    pub nodes: Vec<u8>,
    /// The drives' own clock (heartbeat) runs this many times as fast as the wall clock;
    /// motion follows the SYNCs the master sends.
    #[arg(long, default_value_t = 1.0)]
    pub time_scale: f64,
    /// Faults, as NODE:KIND:ARG: silent:SYNCS, following-error:SYNCS, lose-sync:SYNCS,
    /// fault:SYNCS:CODE (hex), sdo-abort:INDEX:SUB:CODE (hex), e.g. 2:following-error:500.
    #[arg(long)]
    pub fault: Vec<String>,
}

fn hex(s: &str) -> Result<u64, String> {
    u64::from_str_radix(s.trim_start_matches("0x"), 16)
        .map_err(|_| format!("\"{s}\" is not hexadecimal"))
}

/// Reads NODE:KIND:ARGS.
pub fn parse_fault(s: &str) -> Result<(u8, DriveFault), String> {
    let parts: Vec<&str> = s.split(':').collect();
    let bad = || format!("fault \"{s}\" is not NODE:KIND:ARG, e.g. 2:following-error:500");
    let node: u8 = parts.first().and_then(|n| n.parse().ok()).ok_or_else(bad)?;
    let num = |i: usize| -> Result<u64, String> {
        parts.get(i).and_then(|v| v.parse().ok()).ok_or_else(bad)
    };
    let f = match (parts.get(1).copied(), parts.len()) {
        (Some("silent"), 3) => DriveFault::Silent {
            after_syncs: num(2)?,
        },
        (Some("following-error"), 3) => DriveFault::FollowingError {
            after_syncs: num(2)?,
        },
        (Some("lose-sync"), 3) => DriveFault::LoseSync {
            after_syncs: num(2)?,
        },
        (Some("fault"), 4) => DriveFault::Fault {
            after_syncs: num(2)?,
            code: hex(parts[3])? as u16,
        },
        (Some("sdo-abort"), 5) => DriveFault::SdoAbort {
            index: hex(parts[2])? as u16,
            sub: hex(parts[3])? as u8,
            code: hex(parts[4])? as u32,
        },
        _ => return Err(bad()),
    };
    Ok((node, f))
}

/// Runs the drives until killed.
pub async fn run(a: CanopenArgs) -> anyhow::Result<()> {
    if a.nodes.is_empty() || a.nodes.iter().any(|n| !(1..=127).contains(n)) {
        anyhow::bail!("--nodes must be node ids from 1 to 127, e.g. 1,2,3");
    }
    let faults = a
        .fault
        .iter()
        .map(|f| parse_fault(f))
        .collect::<Result<Vec<_>, _>>()
        .map_err(anyhow::Error::msg)?;
    let bus = MemoryBus::new();
    let drives = SimDrives::spawn(&bus, &a.nodes, a.time_scale);
    for (node, f) in faults {
        if !drives.inject(node, f) {
            anyhow::bail!("--fault names node {node}, which is not in --nodes");
        }
    }
    let adapter = spawn_adapter(&bus).context("cannot open a pty for the SLCAN adapter")?;
    crate::pty::symlink_replacing(std::path::Path::new(&adapter.path), &a.slcan_pty).with_context(
        || {
            format!(
                "cannot link {} to the adapter's pty {}",
                a.slcan_pty.display(),
                adapter.path
            )
        },
    )?;
    println!("{}", a.slcan_pty.display());
    eprintln!(
        "machlink-sim: CiA 402 drives at nodes {:?} behind an SLCAN adapter on {} (pty {}); stop with Ctrl-C",
        a.nodes,
        a.slcan_pty.display(),
        adapter.path
    );
    tokio::signal::ctrl_c().await.ok();
    drop(drives);
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn faults_parse_from_the_command_line() {
        assert_eq!(
            parse_fault("2:following-error:500").unwrap(),
            (2, DriveFault::FollowingError { after_syncs: 500 })
        );
        assert_eq!(
            parse_fault("1:sdo-abort:6060:0:06090030").unwrap(),
            (
                1,
                DriveFault::SdoAbort {
                    index: 0x6060,
                    sub: 0,
                    code: 0x0609_0030
                }
            )
        );
        assert!(parse_fault("1:melt:3").is_err());
    }
}
