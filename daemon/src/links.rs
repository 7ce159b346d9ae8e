//! Opening machine links from the configuration: serial GRBL controllers and the GRBL
//! simulators the daemon starts itself.

use crate::config::{LinkConfig, MachineConfig};
use crate::scheduler::LinkOpener;
use futures::future::BoxFuture;
use machlink_protocols::{Link, LinkError};
use std::collections::HashMap;
use std::path::PathBuf;

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
        let modbus = match &machine.link {
            LinkConfig::ModbusTcp(m) => Some(m.settings()),
            LinkConfig::ModbusRtu(m) => Some(m.settings()),
            _ => None,
        };
        if let Some(settings) = modbus {
            return Box::pin(async move {
                let link = machlink_protocols::modbus::ModbusLink::new(settings)
                    .map_err(LinkError::from)?;
                Ok(Box::new(link) as Box<dyn Link>)
            });
        }
        let _port = match &machine.link {
            LinkConfig::Grbl(g) => g.port.clone(),
            LinkConfig::SimGrbl(_) => self
                .sim_ports
                .get(&machine.name)
                .map(|p| p.display().to_string())
                .unwrap_or_default(),
            LinkConfig::ModbusTcp(_) | LinkConfig::ModbusRtu(_) => unreachable!("opened above"),
        };
        Box::pin(async move { Err(LinkError::Protocol("the GRBL link is not built yet".into())) })
    }
}
