//! The socketcan transport on a virtual CAN interface (vcan): frames sent on one socket
//! arrive on another. Where the kernel has no CAN (no vcan module, no permission), the test
//! says why on stderr and passes: the SLCAN and in-memory tests still cover the master.

use machlink_protocols::canopen::socketcan::SocketCanBus;
use machlink_protocols::canopen::{CanBus, CanFrame};
use std::process::Command;
use std::time::Duration;

const IFACE: &str = "vcanml0";

/// Makes `IFACE` (a vcan) and brings it up; the reason when it cannot.
fn make_vcan() -> Result<(), String> {
    if std::path::Path::new(&format!("/sys/class/net/{IFACE}")).exists() {
        return Ok(());
    }
    let _ = Command::new("modprobe").arg("vcan").output();
    let add = Command::new("ip")
        .args(["link", "add", "dev", IFACE, "type", "vcan"])
        .output()
        .map_err(|e| format!("cannot run `ip` ({e})"))?;
    if !add.status.success() {
        return Err(format!(
            "`ip link add dev {IFACE} type vcan` failed: {}",
            String::from_utf8_lossy(&add.stderr).trim()
        ));
    }
    let up = Command::new("ip")
        .args(["link", "set", "up", IFACE])
        .output()
        .map_err(|e| format!("cannot run `ip` ({e})"))?;
    if !up.status.success() {
        return Err(format!(
            "`ip link set up {IFACE}` failed: {}",
            String::from_utf8_lossy(&up.stderr).trim()
        ));
    }
    Ok(())
}

#[tokio::test]
async fn frames_cross_a_virtual_can_interface_or_the_test_says_why_not() {
    if let Err(why) = make_vcan() {
        eprintln!(
            "SKIPPED socketcan transport test: this kernel has no usable CAN ({why}); \
             SLCAN and in-memory tests cover the master"
        );
        return;
    }
    let mut a = SocketCanBus::open(IFACE).expect("opens the vcan");
    let mut b = SocketCanBus::open(IFACE).expect("opens the vcan again");
    let frames = [
        CanFrame::new(0x080, &[]).unwrap(),
        CanFrame::new(0x201, &[0x10, 0x27, 0, 0]).unwrap(),
        CanFrame::with_id(0x1ABC_DEF0, true, &[1, 2, 3, 4, 5, 6, 7, 8]).unwrap(),
    ];
    for f in &frames {
        a.send(f).await.unwrap();
    }
    for f in &frames {
        let got = tokio::time::timeout(Duration::from_secs(5), b.recv())
            .await
            .expect("a frame within 5 s")
            .unwrap();
        assert_eq!(&got, f);
    }
}
