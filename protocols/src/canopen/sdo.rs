//! SDO, the confirmed access to one object of a node's dictionary: the client (machlink's
//! master) and the server (the simulated drive) as no-I/O state machines over 8-byte frames,
//! expedited (up to 4 bytes in one frame) and segmented (7 bytes a frame, toggled), with
//! abort codes by name. Block transfer is not offered; a server aborts it as an unknown command.

use std::fmt;

/// COB-ID of requests to node `n` (client to server).
pub fn request_cob(node: u8) -> u16 {
    0x600 + node as u16
}
/// COB-ID of responses from node `n` (server to client).
pub fn response_cob(node: u8) -> u16 {
    0x580 + node as u16
}

/// An SDO abort code (CiA 301, 7.2.4.3.17).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub struct AbortCode(pub u32);

impl AbortCode {
    pub const TOGGLE: AbortCode = AbortCode(0x0503_0000);
    pub const TIMEOUT: AbortCode = AbortCode(0x0504_0000);
    pub const COMMAND: AbortCode = AbortCode(0x0504_0001);
    pub const UNSUPPORTED_ACCESS: AbortCode = AbortCode(0x0601_0000);
    pub const WRITE_ONLY: AbortCode = AbortCode(0x0601_0001);
    pub const READ_ONLY: AbortCode = AbortCode(0x0601_0002);
    pub const NO_OBJECT: AbortCode = AbortCode(0x0602_0000);
    pub const NOT_MAPPABLE: AbortCode = AbortCode(0x0604_0041);
    pub const PDO_TOO_LONG: AbortCode = AbortCode(0x0604_0042);
    pub const PARAMETER_INCOMPATIBLE: AbortCode = AbortCode(0x0604_0043);
    pub const LENGTH_MISMATCH: AbortCode = AbortCode(0x0607_0010);
    pub const TOO_LONG: AbortCode = AbortCode(0x0607_0012);
    pub const TOO_SHORT: AbortCode = AbortCode(0x0607_0013);
    pub const NO_SUBINDEX: AbortCode = AbortCode(0x0609_0011);
    pub const INVALID_VALUE: AbortCode = AbortCode(0x0609_0030);
    pub const GENERAL: AbortCode = AbortCode(0x0800_0000);
    pub const DEVICE_STATE: AbortCode = AbortCode(0x0800_0022);

    /// The code's meaning in CiA 301's words.
    pub fn name(&self) -> &'static str {
        match self.0 {
            0x0503_0000 => "toggle bit not alternated",
            0x0504_0000 => "SDO protocol timed out",
            0x0504_0001 => "client/server command specifier not valid or unknown",
            0x0504_0002 => "invalid block size",
            0x0504_0003 => "invalid sequence number",
            0x0504_0004 => "CRC error",
            0x0504_0005 => "out of memory",
            0x0601_0000 => "unsupported access to an object",
            0x0601_0001 => "attempt to read a write-only object",
            0x0601_0002 => "attempt to write a read-only object",
            0x0602_0000 => "object does not exist in the object dictionary",
            0x0604_0041 => "object cannot be mapped to the PDO",
            0x0604_0042 => {
                "the number and length of the objects to be mapped would exceed PDO length"
            }
            0x0604_0043 => "general parameter incompatibility",
            0x0604_0047 => "general internal incompatibility in the device",
            0x0606_0000 => "access failed due to a hardware error",
            0x0607_0010 => "data type does not match, length of service parameter does not match",
            0x0607_0012 => "data type does not match, length of service parameter too high",
            0x0607_0013 => "data type does not match, length of service parameter too low",
            0x0609_0011 => "sub-index does not exist",
            0x0609_0030 => "invalid value for parameter",
            0x0609_0031 => "value of parameter written too high",
            0x0609_0032 => "value of parameter written too low",
            0x0609_0036 => "maximum value is less than minimum value",
            0x060A_0023 => "resource not available: SDO connection",
            0x0800_0000 => "general error",
            0x0800_0020 => "data cannot be transferred or stored to the application",
            0x0800_0021 => "data cannot be transferred or stored because of local control",
            0x0800_0022 => {
                "data cannot be transferred or stored because of the present device state"
            }
            0x0800_0023 => "object dictionary not present or its dynamic generation failed",
            0x0800_0024 => "no data available",
            _ => "unknown abort code",
        }
    }
}

impl fmt::Display for AbortCode {
    fn fmt(&self, f: &mut fmt::Formatter) -> fmt::Result {
        write!(f, "0x{:08X} ({})", self.0, self.name())
    }
}

/// Why a transfer failed, as the client sees it.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
pub enum SdoError {
    #[error("aborted the SDO {access} of 0x{index:04X}:{sub:02X} ({name}) with {code}", name = super::od::name(*index))]
    Aborted {
        access: &'static str,
        index: u16,
        sub: u8,
        code: AbortCode,
    },
    /// The server answered something the transfer did not expect.
    #[error("answered the SDO {access} of 0x{index:04X}:{sub:02X} out of protocol: {what}")]
    Protocol {
        access: &'static str,
        index: u16,
        sub: u8,
        what: String,
    },
}

/// What the client does next.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SdoStep {
    /// Send this request and wait for the next response.
    Send([u8; 8]),
    /// The transfer is complete: the data read (empty for a write).
    Done(Vec<u8>),
}

#[derive(Clone, Debug, PartialEq, Eq, Default)]
enum Client {
    #[default]
    Idle,
    DownloadInitiate {
        data: Vec<u8>,
        expedited: bool,
    },
    DownloadSegment {
        data: Vec<u8>,
        offset: usize,
        toggle: bool,
    },
    UploadInitiate,
    UploadSegment {
        buf: Vec<u8>,
        size: Option<usize>,
        toggle: bool,
    },
}

/// Reads the 4-byte little-endian value at `at` of a frame known to hold 8 bytes.
fn le32(d: &[u8; 8], at: usize) -> u32 {
    u32::from_le_bytes([d[at], d[at + 1], d[at + 2], d[at + 3]])
}

fn frame8(data: &[u8]) -> Option<[u8; 8]> {
    data.get(..8)?.try_into().ok()
}

fn header(cmd: u8, index: u16, sub: u8) -> [u8; 8] {
    let i = index.to_le_bytes();
    [cmd, i[0], i[1], sub, 0, 0, 0, 0]
}

/// An abort request or response for `index`:`sub`.
pub fn abort_frame(index: u16, sub: u8, code: AbortCode) -> [u8; 8] {
    let mut f = header(0x80, index, sub);
    f[4..].copy_from_slice(&code.0.to_le_bytes());
    f
}

/// One SDO client: one transfer at a time with one server.
#[derive(Clone, Debug, Default)]
pub struct SdoClient {
    state: Client,
    index: u16,
    sub: u8,
}

impl SdoClient {
    pub fn new() -> SdoClient {
        SdoClient::default()
    }

    fn access(&self) -> &'static str {
        match self.state {
            Client::UploadInitiate | Client::UploadSegment { .. } => "upload",
            _ => "download",
        }
    }

    /// Starts writing `data` to `index`:`sub`: the first request.
    pub fn download(&mut self, index: u16, sub: u8, data: &[u8]) -> [u8; 8] {
        self.index = index;
        self.sub = sub;
        if !data.is_empty() && data.len() <= 4 {
            let n = 4 - data.len() as u8;
            let mut f = header(0x23 | (n << 2), index, sub);
            f[4..4 + data.len()].copy_from_slice(data);
            self.state = Client::DownloadInitiate {
                data: Vec::new(),
                expedited: true,
            };
            f
        } else {
            let mut f = header(0x21, index, sub);
            f[4..].copy_from_slice(&(data.len() as u32).to_le_bytes());
            self.state = Client::DownloadInitiate {
                data: data.to_vec(),
                expedited: false,
            };
            f
        }
    }

    /// Starts reading `index`:`sub`: the first request.
    pub fn upload(&mut self, index: u16, sub: u8) -> [u8; 8] {
        self.index = index;
        self.sub = sub;
        self.state = Client::UploadInitiate;
        header(0x40, index, sub)
    }

    fn protocol(&self, what: impl Into<String>) -> SdoError {
        SdoError::Protocol {
            access: self.access(),
            index: self.index,
            sub: self.sub,
            what: what.into(),
        }
    }

    fn next_segment(data: &[u8], offset: usize, toggle: bool) -> [u8; 8] {
        let n = (data.len() - offset).min(7);
        let last = offset + n == data.len();
        let mut f = [0u8; 8];
        f[0] = ((toggle as u8) << 4) | (((7 - n) as u8) << 1) | last as u8;
        f[1..1 + n].copy_from_slice(&data[offset..offset + n]);
        f
    }

    /// Takes the server's response; never panics, whatever the bytes.
    pub fn on_response(&mut self, data: &[u8]) -> Result<SdoStep, SdoError> {
        let Some(d) = frame8(data) else {
            let e = self.protocol(format!("a response of {} bytes, not 8", data.len()));
            self.state = Client::Idle;
            return Err(e);
        };
        let access = self.access();
        if d[0] == 0x80 {
            self.state = Client::Idle;
            return Err(SdoError::Aborted {
                access,
                index: self.index,
                sub: self.sub,
                code: AbortCode(le32(&d, 4)),
            });
        }
        let scs = d[0] >> 5;
        let same_object = u16::from_le_bytes([d[1], d[2]]) == self.index && d[3] == self.sub;
        let state = std::mem::take(&mut self.state);
        let step = match state {
            Client::Idle => Err(self.protocol("a response with no transfer under way")),
            Client::DownloadInitiate { data, expedited } => {
                if scs != 3 || !same_object {
                    Err(self.protocol(format!("{:02X?} to a download request", d)))
                } else if expedited {
                    Ok(SdoStep::Done(Vec::new()))
                } else {
                    let f = Self::next_segment(&data, 0, false);
                    self.state = Client::DownloadSegment {
                        data,
                        offset: 0,
                        toggle: false,
                    };
                    Ok(SdoStep::Send(f))
                }
            }
            Client::DownloadSegment {
                data,
                offset,
                toggle,
            } => {
                if scs != 1 || ((d[0] >> 4) & 1 == 1) != toggle {
                    Err(self.protocol(format!("{:02X?} to a download segment", d)))
                } else {
                    let offset = offset + (data.len() - offset).min(7);
                    if offset >= data.len() {
                        Ok(SdoStep::Done(Vec::new()))
                    } else {
                        let f = Self::next_segment(&data, offset, !toggle);
                        self.state = Client::DownloadSegment {
                            data,
                            offset,
                            toggle: !toggle,
                        };
                        Ok(SdoStep::Send(f))
                    }
                }
            }
            Client::UploadInitiate => {
                if scs != 2 || !same_object {
                    Err(self.protocol(format!("{:02X?} to an upload request", d)))
                } else {
                    let (e, s) = (d[0] & 2 != 0, d[0] & 1 != 0);
                    if e {
                        let n = if s { 4 - ((d[0] >> 2) & 3) as usize } else { 4 };
                        Ok(SdoStep::Done(d[4..4 + n].to_vec()))
                    } else {
                        let size = s.then(|| le32(&d, 4) as usize);
                        self.state = Client::UploadSegment {
                            buf: Vec::new(),
                            size,
                            toggle: false,
                        };
                        Ok(SdoStep::Send([0x60, 0, 0, 0, 0, 0, 0, 0]))
                    }
                }
            }
            Client::UploadSegment {
                mut buf,
                size,
                toggle,
            } => {
                if scs != 0 || ((d[0] >> 4) & 1 == 1) != toggle {
                    Err(self.protocol(format!("{:02X?} to an upload segment request", d)))
                } else {
                    let n = 7 - ((d[0] >> 1) & 7) as usize;
                    buf.extend_from_slice(&d[1..1 + n]);
                    let last = d[0] & 1 == 1;
                    if size.is_some_and(|s| buf.len() > s) || buf.len() > 1 << 20 {
                        Err(self.protocol(format!(
                            "more data ({} bytes) than the {} bytes announced",
                            buf.len(),
                            size.unwrap_or(1 << 20)
                        )))
                    } else if last {
                        if size.is_some_and(|s| buf.len() != s) {
                            Err(self.protocol(format!(
                                "{} bytes where {} were announced",
                                buf.len(),
                                size.unwrap_or(0)
                            )))
                        } else {
                            Ok(SdoStep::Done(buf))
                        }
                    } else {
                        let t = !toggle;
                        self.state = Client::UploadSegment {
                            buf,
                            size,
                            toggle: t,
                        };
                        Ok(SdoStep::Send([
                            0x60 | ((t as u8) << 4),
                            0,
                            0,
                            0,
                            0,
                            0,
                            0,
                            0,
                        ]))
                    }
                }
            }
        };
        step
    }

    /// Gives up the transfer under way (after a timeout); the abort request to send.
    pub fn cancel(&mut self, code: AbortCode) -> [u8; 8] {
        self.state = Client::Idle;
        abort_frame(self.index, self.sub, code)
    }
}

/// What an SDO server serves: a node's object dictionary.
pub trait ObjectAccess {
    /// The entry's value as little-endian bytes.
    fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, AbortCode>;
    /// Writes the entry; the server hands over exactly the bytes the client sent.
    fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode>;
}

#[derive(Clone, Debug, Default)]
enum Server {
    #[default]
    Idle,
    Download {
        index: u16,
        sub: u8,
        buf: Vec<u8>,
        size: Option<usize>,
        toggle: bool,
    },
    Upload {
        index: u16,
        sub: u8,
        data: Vec<u8>,
        offset: usize,
        toggle: bool,
    },
}

/// The most a segmented download may announce (a server's buffer).
pub const MAX_DOWNLOAD: usize = 4096;

/// One SDO server: answers one client's requests against an [`ObjectAccess`].
#[derive(Clone, Debug, Default)]
pub struct SdoServer {
    state: Server,
}

impl SdoServer {
    pub fn new() -> SdoServer {
        SdoServer::default()
    }

    /// Answers one request (None: no answer, as after an abort from the client). Never panics,
    /// whatever the bytes.
    pub fn on_request(&mut self, data: &[u8], od: &mut dyn ObjectAccess) -> Option<[u8; 8]> {
        let d = frame8(data)?;
        let (index, sub) = (u16::from_le_bytes([d[1], d[2]]), d[3]);
        let state = std::mem::take(&mut self.state);
        let abort = |i: u16, s: u8, c: AbortCode| Some(abort_frame(i, s, c));
        match d[0] >> 5 {
            // initiate download
            1 => {
                let (e, s) = (d[0] & 2 != 0, d[0] & 1 != 0);
                if e {
                    let n = if s { 4 - ((d[0] >> 2) & 3) as usize } else { 4 };
                    match od.write(index, sub, &d[4..4 + n]) {
                        Ok(()) => Some(header(0x60, index, sub)),
                        Err(c) => abort(index, sub, c),
                    }
                } else {
                    let size = s.then(|| le32(&d, 4) as usize);
                    if size.is_some_and(|n| n > MAX_DOWNLOAD) {
                        return abort(index, sub, AbortCode(0x0504_0005));
                    }
                    self.state = Server::Download {
                        index,
                        sub,
                        buf: Vec::new(),
                        size,
                        toggle: false,
                    };
                    Some(header(0x60, index, sub))
                }
            }
            // download segment
            0 => {
                let Server::Download {
                    index,
                    sub,
                    mut buf,
                    size,
                    toggle,
                } = state
                else {
                    return abort(0, 0, AbortCode::COMMAND);
                };
                if ((d[0] >> 4) & 1 == 1) != toggle {
                    return abort(index, sub, AbortCode::TOGGLE);
                }
                let n = 7 - ((d[0] >> 1) & 7) as usize;
                buf.extend_from_slice(&d[1..1 + n]);
                if buf.len() > size.unwrap_or(MAX_DOWNLOAD) {
                    return abort(index, sub, AbortCode::TOO_LONG);
                }
                let reply = [0x20 | ((toggle as u8) << 4), 0, 0, 0, 0, 0, 0, 0];
                if d[0] & 1 == 1 {
                    if size.is_some_and(|s| s != buf.len()) {
                        return abort(index, sub, AbortCode::LENGTH_MISMATCH);
                    }
                    if let Err(c) = od.write(index, sub, &buf) {
                        return abort(index, sub, c);
                    }
                } else {
                    self.state = Server::Download {
                        index,
                        sub,
                        buf,
                        size,
                        toggle: !toggle,
                    };
                }
                Some(reply)
            }
            // initiate upload
            2 => match od.read(index, sub) {
                Err(c) => abort(index, sub, c),
                Ok(v) if !v.is_empty() && v.len() <= 4 => {
                    let n = 4 - v.len() as u8;
                    let mut f = header(0x43 | (n << 2), index, sub);
                    f[4..4 + v.len()].copy_from_slice(&v);
                    Some(f)
                }
                Ok(v) => {
                    let mut f = header(0x41, index, sub);
                    f[4..].copy_from_slice(&(v.len() as u32).to_le_bytes());
                    self.state = Server::Upload {
                        index,
                        sub,
                        data: v,
                        offset: 0,
                        toggle: false,
                    };
                    Some(f)
                }
            },
            // upload segment
            3 => {
                let Server::Upload {
                    index,
                    sub,
                    data,
                    offset,
                    toggle,
                } = state
                else {
                    return abort(0, 0, AbortCode::COMMAND);
                };
                if ((d[0] >> 4) & 1 == 1) != toggle {
                    return abort(index, sub, AbortCode::TOGGLE);
                }
                let n = (data.len() - offset).min(7);
                let last = offset + n == data.len();
                let mut f = [0u8; 8];
                f[0] = ((toggle as u8) << 4) | (((7 - n) as u8) << 1) | last as u8;
                f[1..1 + n].copy_from_slice(&data[offset..offset + n]);
                if !last {
                    self.state = Server::Upload {
                        index,
                        sub,
                        data,
                        offset: offset + n,
                        toggle: !toggle,
                    };
                }
                Some(f)
            }
            // abort from the client
            4 => None,
            _ => abort(index, sub, AbortCode::COMMAND),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::collections::BTreeMap;

    #[derive(Default)]
    struct Dict(BTreeMap<(u16, u8), Vec<u8>>);
    impl ObjectAccess for Dict {
        fn read(&mut self, index: u16, sub: u8) -> Result<Vec<u8>, AbortCode> {
            self.0
                .get(&(index, sub))
                .cloned()
                .ok_or(AbortCode::NO_OBJECT)
        }
        fn write(&mut self, index: u16, sub: u8, data: &[u8]) -> Result<(), AbortCode> {
            if index == 0x1000 {
                return Err(AbortCode::READ_ONLY);
            }
            self.0.insert((index, sub), data.to_vec());
            Ok(())
        }
    }

    /// Runs a transfer between a client and a server to the end.
    fn run(client: &mut SdoClient, first: [u8; 8], dict: &mut Dict) -> Result<Vec<u8>, SdoError> {
        let mut server = SdoServer::new();
        let mut req = first;
        for _ in 0..10_000 {
            let resp = server.on_request(&req, dict).expect("an answer");
            match client.on_response(&resp)? {
                SdoStep::Send(r) => req = r,
                SdoStep::Done(v) => return Ok(v),
            }
        }
        panic!("the transfer never ended")
    }

    #[test]
    fn expedited_and_segmented_transfers_carry_every_length() {
        let mut dict = Dict::default();
        for len in 0..40usize {
            let value: Vec<u8> = (0..len as u8).map(|b| b.wrapping_mul(37)).collect();
            let mut c = SdoClient::new();
            let first = c.download(0x2000, 3, &value);
            assert_eq!(run(&mut c, first, &mut dict).unwrap(), Vec::<u8>::new());
            let first = c.upload(0x2000, 3);
            assert_eq!(run(&mut c, first, &mut dict).unwrap(), value, "{len} bytes");
        }
    }

    #[test]
    fn aborts_come_back_by_name() {
        let mut dict = Dict::default();
        let mut c = SdoClient::new();
        let first = c.upload(0x6099, 0);
        let e = run(&mut c, first, &mut dict).unwrap_err();
        assert_eq!(
            e.to_string(),
            "aborted the SDO upload of 0x6099:00 (object) with 0x06020000 (object does not exist in the object dictionary)"
        );
        let first = c.download(0x1000, 0, &[1, 2, 3, 4]);
        let e = run(&mut c, first, &mut dict).unwrap_err();
        assert!(
            e.to_string()
                .contains("attempt to write a read-only object"),
            "{e}"
        );
    }

    #[test]
    fn a_wrong_toggle_is_refused_by_both_ends() {
        let mut dict = Dict::default();
        dict.0.insert((0x1008, 0), b"machlink drive".to_vec());
        let mut s = SdoServer::new();
        let r = s.on_request(&header(0x40, 0x1008, 0), &mut dict).unwrap();
        assert_eq!(r[0], 0x41);
        // first segment request with toggle 1 instead of 0
        let r = s
            .on_request(&[0x70, 0, 0, 0, 0, 0, 0, 0], &mut dict)
            .unwrap();
        assert_eq!(r, abort_frame(0x1008, 0, AbortCode::TOGGLE));
        let mut c = SdoClient::new();
        c.upload(0x1008, 0);
        assert!(matches!(
            c.on_response(&[0x41, 0x08, 0x10, 0, 14, 0, 0, 0]),
            Ok(SdoStep::Send(_))
        ));
        assert!(c.on_response(&[0x10, 1, 2, 3, 4, 5, 6, 7]).is_err());
    }
}
