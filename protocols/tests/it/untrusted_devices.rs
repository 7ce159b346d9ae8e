//! A device is untrusted: a GRBL controller that sends a line without end, or floods the
//! link, is cut off with an error that says so, and what it sends reaches the link printable.

use machlink_protocols::grbl::{GrblLink, GrblOptions};
use machlink_protocols::untrusted::Guarded;
use machlink_protocols::LinkError;
use tokio::io::{AsyncReadExt, AsyncWriteExt, DuplexStream};

/// A controller that greets, answers `$I`, then does `then` with the line.
async fn device(mut io: DuplexStream, then: &'static [u8], repeat: bool) {
    io.write_all(b"Grbl 1.1h ['$' for help]\r\n").await.unwrap();
    let mut buf = [0u8; 64];
    let mut got = Vec::new();
    while !got.ends_with(b"$I\n") {
        let n = io.read(&mut buf).await.unwrap();
        got.extend_from_slice(&buf[..n]);
    }
    io.write_all(b"[VER:1.1h.20190825:]\r\n[OPT:V,15,128]\r\nok\r\n")
        .await
        .unwrap();
    loop {
        if io.write_all(then).await.is_err() || !repeat {
            break;
        }
    }
    // keep the line open
    let _ = io.read(&mut buf).await;
}

async fn link_to(then: &'static [u8], repeat: bool) -> GrblLink {
    let (a, b) = tokio::io::duplex(1 << 16);
    tokio::spawn(device(b, then, repeat));
    GrblLink::from_stream(Guarded::new(a), GrblOptions::default())
        .await
        .expect("the controller greets")
}

#[tokio::test(start_paused = true)]
async fn a_line_without_end_cuts_the_device_off() {
    static ENDLESS: [u8; 4096] = [b'x'; 4096];
    let mut link = link_to(&ENDLESS, false).await;
    let e = link.send_setting("$$").await.unwrap_err();
    assert!(matches!(e, LinkError::Io(_)), "{e}");
    assert!(e.to_string().contains("longer than 1024 bytes"), "{e}");
}

#[tokio::test(start_paused = true)]
async fn a_flooding_device_is_cut_off() {
    let mut link = link_to(b"[MSG:spam]\r\n", true).await;
    let e = link.send_setting("$$").await.unwrap_err();
    assert!(e.to_string().contains("cut off as flooding"), "{e}");
}

#[tokio::test(start_paused = true)]
async fn control_characters_never_reach_the_link() {
    let mut link = link_to(b"[MSG:\x1b[31mred\x07\xff]\r\nok\r\n", false).await;
    let printed = link.send_setting("$$").await.unwrap();
    assert_eq!(printed, "[MSG:[31mred\u{FFFD}]");
}
