//! `machlink-sim`: run a simulated device on a pty or a TCP port.

fn main() {
    eprintln!("machlink-sim: no devices yet");
    std::process::exit(2);
}
