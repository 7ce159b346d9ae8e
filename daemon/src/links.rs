//! Opening machine links from the configuration: serial GRBL controllers and the GRBL
//! simulators the daemon starts itself.

use crate::config::{LinkConfig, MachineConfig};
use crate::scheduler::LinkOpener;
use futures::future::BoxFuture;
use machlink_protocols::grbl::{GrblLink, GrblOptions};
use machlink_protocols::{Control, Link, LinkError, LinkEvent, Program, StreamEnd};
use std::collections::HashMap;
use std::path::PathBuf;
use tokio::sync::{mpsc, watch};

/// The daemon's opener: a machine's link by its config; `sim-grbl` machines use the
/// pseudo-terminal of the simulator the daemon started for them.
#[derive(Default)]
pub struct ConfigOpener {
    /// The pty of each simulated machine, by machine name.
    pub sim_ports: HashMap<String, PathBuf>,
}

impl LinkOpener for ConfigOpener {
    fn open(
        &self,
        machine: &MachineConfig,
    ) -> BoxFuture<'static, Result<Box<dyn Link>, LinkError>> {
        if let Some(open) = self.open_sewing(machine) {
            return open;
        }
        let (port, opts, unlock) = match &machine.link {
            LinkConfig::Grbl(g) => (
                g.port.clone(),
                GrblOptions {
                    baud: g.baud,
                    check_first: g.check_first,
                    ..Default::default()
                },
                g.auto_unlock,
            ),
            LinkConfig::SimGrbl(_) => (
                self.sim_ports
                    .get(&machine.name)
                    .map(|p| p.display().to_string())
                    .unwrap_or_default(),
                GrblOptions::default(),
                true,
            ),
            LinkConfig::ModbusTcp(m) => return open_modbus(m.settings()),
            LinkConfig::ModbusRtu(m) => return open_modbus(m.settings()),
            LinkConfig::Sewing(_) | LinkConfig::SimSewing(_) => unreachable!("opened above"),
        };
        Box::pin(async move {
            let link = GrblLink::open(&port, opts).await?;
            Ok(Box::new(GrblMachine { link, unlock }) as Box<dyn Link>)
        })
    }
}

/// A Modbus motion-block link (TCP or RTU); it connects on its first request.
fn open_modbus(
    settings: machlink_protocols::modbus::ModbusSettings,
) -> BoxFuture<'static, Result<Box<dyn Link>, LinkError>> {
    Box::pin(async move {
        let link =
            machlink_protocols::modbus::ModbusLink::new(settings).map_err(LinkError::from)?;
        Ok(Box::new(link) as Box<dyn Link>)
    })
}

impl ConfigOpener {
    /// The link of a pattern sewing machine (`sewing` or `sim-sewing`); None for other links.
    fn open_sewing(
        &self,
        machine: &MachineConfig,
    ) -> Option<BoxFuture<'static, Result<Box<dyn Link>, LinkError>>> {
        use machlink_protocols::sewing::link::{SewingLink, SewingTiming};
        let (port, baud) = match &machine.link {
            LinkConfig::Sewing(s) => (s.port.clone(), s.baud),
            LinkConfig::SimSewing(_) => (
                self.sim_ports
                    .get(&machine.name)
                    .map(|p| p.display().to_string())
                    .unwrap_or_default(),
                115_200,
            ),
            _ => return None,
        };
        Some(Box::pin(async move {
            let link = SewingLink::open(&port, baud, SewingTiming::default())?;
            Ok(Box::new(link) as Box<dyn Link>)
        }))
    }
}

/// A GRBL link that, with `unlock`, clears an alarm lock left by an earlier job (`$X`)
/// before streaming, and says so.
pub struct GrblMachine {
    pub link: GrblLink,
    pub unlock: bool,
}

impl Link for GrblMachine {
    fn stream<'a>(
        &'a mut self,
        program: &'a Program,
        from: usize,
        events: mpsc::UnboundedSender<LinkEvent>,
        control: watch::Receiver<Control>,
    ) -> BoxFuture<'a, Result<StreamEnd, LinkError>> {
        Box::pin(async move {
            let status = self.link.query_status().await?;
            if status.state == "Alarm" {
                if !self.unlock {
                    return Err(LinkError::Protocol(
                        "the machine is in alarm: clear its cause, unlock it ($X) or set auto_unlock = true".into(),
                    ));
                }
                self.link.send_setting("$X").await?;
                let _ = events.send(LinkEvent::Message(
                    "the machine was in alarm from an earlier job; unlocked it with $X".into(),
                ));
            }
            self.link.stream(program, from, events, control).await
        })
    }
}
