//! The `gige` camera backend: a pure-Rust GigE Vision client (GVCP control, GVSP
//! stream) that always builds, works with our emulator, Aravis's
//! `arv-fake-gv-camera-0.8` and real cameras (GenICam XML plain or zipped; Mono8, Mono16).
//!
//! Open: take control (CCP), read the XML from the first URL register, resolve the
//! features it needs, open stream channel 0 towards a local UDP socket, put the camera
//! in software-trigger acquisition. A heartbeat task keeps control (READREG CCP at a
//! third of the camera's heartbeat timeout); if the camera stops answering, the next
//! `grab` fails with that reason. `grab` triggers one frame and reassembles it; missing
//! packets are asked again (PACKETRESEND) a bounded number of times, then the frame is
//! refused as incomplete, naming the missing packets; a frame of another size or pixel
//! format than the camera declared at open is refused too. Such a lost frame (or a
//! trigger with no packet at all, e.g. after a forged leader in the way) is dropped and
//! the camera triggered again, as Aravis drops a bad buffer and keeps streaming: a grab
//! fails only after [`GRAB_ATTEMPTS`] lost frames in a row ([`GigeCamera::dropped_frames`]
//! counts them); a lost link (heartbeat, control channel) fails at once. No frame is
//! ever returned unless every byte of it arrived.

pub mod client;
pub mod genicam;

use crate::camera::{Camera, CameraInfo, Frame, FrameMeta};
use crate::error::DriverError;
use async_trait::async_trait;
use client::Gvcp;
use genicam::{GenICam, Location};
use protocol::gige::gvcp::{AckBody, Command, CommandPacket, FLAG_ACK_REQUIRED, PORT};
use protocol::gige::gvsp::{self, Assembler, GvspError, Negotiated, Packet};
use protocol::gige::{bootstrap as bs, parse_local_url, pfnc};
use protocol::{MonoImage, Pixels};
use std::net::{IpAddr, SocketAddr};
use std::sync::{Arc, Mutex};
use std::time::Duration;
use tokio::net::UdpSocket;
use tokio::task::JoinHandle;

pub use link_spec::gige::GigeOptions;

/// A device that answered discovery.
#[derive(Clone, Debug, PartialEq)]
pub struct Discovered {
    pub address: SocketAddr,
    pub vendor: String,
    pub model: String,
    pub serial: String,
    pub user_name: String,
}

impl Discovered {
    /// Aravis's device id: `vendor-model-serial`.
    pub fn id(&self) -> String {
        format!("{}-{}-{}", self.vendor, self.model, self.serial)
    }
    fn matches(&self, name: &str) -> bool {
        [
            self.id(),
            self.serial.clone(),
            self.user_name.clone(),
            self.model.clone(),
        ]
        .iter()
        .any(|s| !s.is_empty() && s == name)
    }
}

fn cstr(b: &[u8]) -> String {
    let end = b.iter().position(|&c| c == 0).unwrap_or(b.len());
    String::from_utf8_lossy(&b[..end]).trim().to_string()
}

/// Sends DISCOVERY to `targets` (broadcast or unicast addresses, port 3956 usually) and
/// collects the answers for `wait`.
pub async fn discover(
    targets: &[SocketAddr],
    wait: Duration,
) -> Result<Vec<Discovered>, DriverError> {
    let err = |m: String| DriverError::Transport {
        device: "GigE Vision discovery".into(),
        message: m,
    };
    let sock = UdpSocket::bind("0.0.0.0:0")
        .await
        .map_err(|e| err(format!("bind: {e}")))?;
    sock.set_broadcast(true)
        .map_err(|e| err(format!("SO_BROADCAST: {e}")))?;
    let pkt = CommandPacket {
        flags: FLAG_ACK_REQUIRED | protocol::gige::gvcp::FLAG_DISCOVERY_BROADCAST_ACK,
        req_id: 0xFFFF,
        command: Command::Discovery,
    }
    .encode();
    for t in targets {
        // An unreachable broadcast address is not an error of discovery as a whole.
        let _ = sock.send_to(&pkt, t).await;
    }
    let mut found: Vec<Discovered> = Vec::new();
    let mut buf = vec![0u8; 1024];
    let deadline = tokio::time::Instant::now() + wait;
    while let Ok(Ok((n, from))) = tokio::time::timeout_at(deadline, sock.recv_from(&mut buf)).await
    {
        let Ok(ack) = protocol::gige::gvcp::Ack::decode(&buf[..n]) else {
            continue;
        };
        let AckBody::Discovery(d) = ack.body else {
            continue;
        };
        if d.len() < bs::DISCOVERY_LEN {
            continue;
        }
        let s = |a: u32, l: usize| cstr(&d[a as usize..a as usize + l]);
        let ip = IpAddr::from([d[0x24], d[0x25], d[0x26], d[0x27]]);
        // Answer from the port that replied (a device on a non-standard port, as in tests).
        let address = if ip.is_unspecified() {
            from
        } else {
            SocketAddr::new(ip, from.port())
        };
        let dev = Discovered {
            address,
            vendor: s(bs::MANUFACTURER, 32),
            model: s(bs::MODEL, 32),
            serial: s(bs::SERIAL_NUMBER, 16),
            user_name: s(bs::USER_NAME, 16),
        };
        if !found.contains(&dev) {
            found.push(dev);
        }
    }
    Ok(found)
}

/// Resolves a camera given as `ip`, `ip:port` or a device name (`vendor-model-serial`,
/// serial or user name, found by discovery on loopback and the broadcast address).
pub async fn resolve(camera: &str) -> Result<SocketAddr, DriverError> {
    if let Ok(a) = camera.parse::<SocketAddr>() {
        return Ok(a);
    }
    if let Ok(ip) = camera.parse::<IpAddr>() {
        return Ok(SocketAddr::new(ip, PORT));
    }
    let targets: Vec<SocketAddr> = vec![
        SocketAddr::from(([255, 255, 255, 255], PORT)),
        SocketAddr::from(([127, 0, 0, 1], PORT)),
    ];
    let found = discover(&targets, Duration::from_millis(1000)).await?;
    found
        .iter()
        .find(|d| d.matches(camera))
        .map(|d| d.address)
        .ok_or_else(|| DriverError::NotAvailable {
            backend: "gige".into(),
            reason: format!(
                "no GigE Vision camera named `{camera}` answered discovery within 1 s (found: {})",
                if found.is_empty() {
                    "none".to_string()
                } else {
                    found
                        .iter()
                        .map(|d| format!("{} at {}", d.id(), d.address))
                        .collect::<Vec<_>>()
                        .join(", ")
                }
            ),
        })
}

struct Features {
    xml: GenICam,
}

impl Features {
    fn reg(&self, device: &str, f: &str) -> Result<Location, DriverError> {
        self.xml.locate(f).map_err(|m| DriverError::Unsupported {
            device: device.into(),
            message: m,
        })
    }
}

async fn read_feature(ctl: &mut Gvcp, loc: &Location) -> Result<i64, DriverError> {
    match *loc {
        Location::Constant(v) => Ok(v),
        Location::Register {
            address,
            length,
            little_endian,
            field,
            ..
        } => {
            let raw = if length == 4 {
                ctl.read_reg(address).await? as u64
            } else {
                let b = ctl.read_mem(address, length as usize).await?;
                let mut v = 0u64;
                let it: Vec<u8> = if little_endian {
                    b.iter().rev().copied().collect()
                } else {
                    b
                };
                for x in it {
                    v = (v << 8) | x as u64;
                }
                v
            };
            let raw = if little_endian && length == 4 {
                (raw as u32).swap_bytes() as u64
            } else {
                raw
            };
            Ok(field_value(raw, field) as i64)
        }
    }
}

/// `width` low bits set (all 64 for 64 or more, none for 0).
fn low_bits(width: u32) -> u64 {
    u64::MAX
        .checked_shr(64u32.saturating_sub(width))
        .unwrap_or(0)
}

/// A MaskedIntReg field `(shift, width)` of a register's value (the whole value
/// without a field). Shifts are checked: a field outside the register reads as 0.
fn field_value(raw: u64, field: Option<(u32, u32)>) -> u64 {
    match field {
        Some((shift, width)) => raw.checked_shr(shift).unwrap_or(0) & low_bits(width),
        None => raw,
    }
}

/// A 32-bit register `old` with its field `(shift, width)` set to `v` (a field outside
/// the register changes nothing).
fn merge_field(old: u32, v: u32, (shift, width): (u32, u32)) -> u32 {
    let mask = low_bits(width).checked_shl(shift).unwrap_or(0) as u32;
    (old & !mask) | (v.checked_shl(shift).unwrap_or(0) & mask)
}

async fn write_feature(
    ctl: &mut Gvcp,
    loc: &Location,
    value: i64,
    what: &str,
) -> Result<(), DriverError> {
    match *loc {
        Location::Constant(v) if v == value => Ok(()),
        Location::Constant(v) => Err(ctl.violation(format!(
            "{what}: the camera fixes it at {v}, cannot set {value}"
        ))),
        Location::Register {
            address,
            length: 4,
            little_endian,
            field,
            ..
        } => {
            let mut v = value as u32;
            if let Some((shift, width)) = field {
                let old = ctl.read_reg(address).await?;
                let old = if little_endian { old.swap_bytes() } else { old };
                v = merge_field(old, v, (shift, width));
            }
            if little_endian {
                v = v.swap_bytes();
            }
            ctl.write_reg(address, v).await
        }
        Location::Register { length, .. } => Err(ctl.violation(format!(
            "{what}: {length}-byte registers are not written by this driver"
        ))),
    }
}

async fn read_float(ctl: &mut Gvcp, loc: &Location) -> Result<f64, DriverError> {
    let v = read_feature(ctl, loc).await?;
    Ok(match loc {
        Location::Register {
            float: true,
            length: 4,
            ..
        } => f32::from_bits(v as u32) as f64,
        Location::Register {
            float: true,
            length: 8,
            ..
        } => f64::from_bits(v as u64),
        _ => v as f64,
    })
}

/// A GigE Vision camera in software-trigger mode.
pub struct GigeCamera {
    ctl: Arc<tokio::sync::Mutex<Gvcp>>,
    stream: UdpSocket,
    device: String,
    info: CameraInfo,
    opts: GigeOptions,
    pixel_format: u32,
    negotiated: Negotiated,
    packet_size: u32,
    resend: bool,
    trigger: (Location, i64),
    exposure: Option<Location>,
    gain: Option<Location>,
    tick_hz: u64,
    last_block: Option<u16>,
    heartbeat_error: Arc<Mutex<Option<String>>>,
    heartbeat: JoinHandle<()>,
    sequence: u64,
    rx: Vec<u8>,
    /// Where GVSP comes from: the camera's address and stream source port (0: the
    /// camera does not report it, any port of that address is taken).
    camera_stream: SocketAddr,
    stray: u64,
    /// Frames lost and triggered again (see [`GRAB_ATTEMPTS`]).
    dropped: u64,
}

impl Drop for GigeCamera {
    fn drop(&mut self) {
        self.heartbeat.abort();
        // Give the camera back: close the stream channel and release control, without
        // waiting for acks (a camera that is gone must not block the drop).
        if let Ok(ctl) = self.ctl.try_lock() {
            for (a, v) in [(bs::SCP0, 0u32), (bs::CCP, 0)] {
                let pkt = CommandPacket {
                    flags: 0,
                    req_id: 1,
                    command: Command::WriteReg(vec![(a, v)]),
                }
                .encode();
                let _ = ctl.sock.try_send_to(&pkt, ctl.peer);
            }
        }
    }
}

impl GigeCamera {
    /// Opens the camera `camera` (`ip`, `ip:port` or device name).
    pub async fn open(camera: &str, opts: GigeOptions) -> Result<Self, DriverError> {
        let addr = resolve(camera).await?;
        Self::open_addr(addr, opts).await
    }

    pub async fn open_addr(addr: SocketAddr, opts: GigeOptions) -> Result<Self, DriverError> {
        let mut ctl = Gvcp::connect(addr, opts.timeout, opts.retries).await?;
        match Self::set_up(&mut ctl, addr, opts).await {
            Ok(finish) => Ok(finish(ctl)),
            Err(e) => {
                // Give control back at once rather than blocking every client until the
                // heartbeat expires (pointless if the camera is not answering at all).
                if !matches!(
                    e,
                    DriverError::Timeout { .. } | DriverError::Transport { .. }
                ) {
                    let _ = ctl.write_reg(bs::CCP, 0).await;
                }
                Err(e)
            }
        }
    }

    /// Everything of `open_addr` that talks to the camera; returns how to finish once
    /// the control channel is handed over.
    async fn set_up(
        ctl: &mut Gvcp,
        addr: SocketAddr,
        opts: GigeOptions,
    ) -> Result<impl FnOnce(Gvcp) -> Self, DriverError> {
        let device = ctl.device.clone();
        // Who is it (and is anything there at all).
        let ident = ctl.read_mem(0, bs::DISCOVERY_LEN).await?;
        let model = cstr(&ident[bs::MODEL as usize..bs::MODEL as usize + 32]);
        let vendor = cstr(&ident[bs::MANUFACTURER as usize..bs::MANUFACTURER as usize + 32]);
        let serial = cstr(&ident[bs::SERIAL_NUMBER as usize..bs::SERIAL_NUMBER as usize + 16]);
        ctl.write_reg(bs::CCP, bs::CCP_CONTROL).await.map_err(|e| match e {
            DriverError::Refused { code: 0x8006, .. } => DriverError::InvalidState {
                device: device.clone(),
                message: "another client controls the camera (CCP refused with ACCESS_DENIED); wait for its heartbeat to expire".into(),
            },
            e => e,
        })?;
        let url = ctl.read_mem(bs::FIRST_URL, bs::URL_LEN).await?;
        let (file, xml_addr, xml_size) =
            parse_local_url(&url).map_err(|e| DriverError::Unsupported {
                device: device.clone(),
                message: e.to_string(),
            })?;
        // The size is the camera's word: bounded like an archive's declared size.
        if xml_size as usize > protocol::gige::MAX_XML_SIZE {
            return Err(ctl.violation(format!(
                "GenICam XML URL `{}`: size {xml_size} bytes is more than the {} bytes a GenICam XML may have (MAX_XML_SIZE)",
                cstr(&url),
                protocol::gige::MAX_XML_SIZE
            )));
        }
        let raw = ctl.read_mem(xml_addr, xml_size as usize).await?;
        // Many cameras ship their XML zipped (one file in the archive).
        let xml = if file.to_ascii_lowercase().ends_with(".zip") {
            let (_, x) =
                protocol::gige::zip::first_file(&raw).map_err(|m| DriverError::Protocol {
                    device: device.clone(),
                    message: format!("GenICam XML `{file}`: {m}"),
                })?;
            String::from_utf8_lossy(&x).into_owned()
        } else {
            cstr(&raw)
        };
        let xml = GenICam::new(xml);
        let f = Features { xml };
        let width = read_feature(ctl, &f.reg(&device, "Width")?).await? as u32;
        let height = read_feature(ctl, &f.reg(&device, "Height")?).await? as u32;
        let pixel_format = read_feature(ctl, &f.reg(&device, "PixelFormat")?).await? as u32;
        let bit_depth = match pixel_format {
            pfnc::MONO8 => 8,
            pfnc::MONO16 => 16,
            other => {
                return Err(DriverError::Unsupported {
                    device,
                    message: format!(
                        "PixelFormat is {} ({}); this driver takes Mono8 or Mono16: set the camera's PixelFormat",
                        pfnc::name(other),
                        f.xml.enum_name("PixelFormat", other as i64).unwrap_or_default()
                    ),
                })
            }
        };
        // Every leader must match this; nothing larger is ever allocated for a frame.
        let negotiated =
            Negotiated::new(width, height, pixel_format).map_err(|e| DriverError::Unsupported {
                device: device.clone(),
                message: e.to_string(),
            })?;
        let caps = ctl.read_reg(bs::GVCP_CAPABILITY).await?;
        let tick_hz = ((ctl.read_reg(bs::TICK_FREQUENCY_HIGH).await? as u64) << 32)
            | ctl.read_reg(bs::TICK_FREQUENCY_LOW).await? as u64;
        if let Some(ms) = opts.heartbeat_timeout_ms {
            ctl.write_reg(bs::HEARTBEAT_TIMEOUT, ms).await?;
        }
        let hb_ms = ctl.read_reg(bs::HEARTBEAT_TIMEOUT).await?.max(300);
        // Stop whatever acquisition a previous client left running.
        if f.xml.has("AcquisitionStop") {
            let loc = f.reg(&device, "AcquisitionStop")?;
            let v = f
                .xml
                .command_value("AcquisitionStop")
                .map_err(|m| ctl.violation(m))?;
            write_feature(ctl, &loc, v, "AcquisitionStop").await?;
        }
        // Stream channel: to a local socket on the interface that reaches the camera.
        let local_ip = {
            let probe = std::net::UdpSocket::bind(if addr.ip().is_loopback() {
                "127.0.0.1:0"
            } else {
                "0.0.0.0:0"
            })
            .and_then(|s| s.connect(addr).map(|_| s))
            .and_then(|s| s.local_addr())
            .map_err(|e| DriverError::Transport {
                device: device.clone(),
                message: format!("finding the local address towards the camera: {e}"),
            })?;
            probe.ip()
        };
        let stream =
            stream_socket(SocketAddr::new(local_ip, 0)).map_err(|e| DriverError::Transport {
                device: device.clone(),
                message: format!("binding the stream socket: {e}"),
            })?;
        let port = stream
            .local_addr()
            .map_err(|e| DriverError::Transport {
                device: device.clone(),
                message: e.to_string(),
            })?
            .port();
        let IpAddr::V4(ip4) = local_ip else {
            return Err(DriverError::Unsupported {
                device,
                message: "GigE Vision streams over IPv4 only".into(),
            });
        };
        ctl.write_reg(bs::SCPS0, opts.packet_size & 0xFFFF).await?;
        let packet_size = ctl.read_reg(bs::SCPS0).await? & 0xFFFF;
        if packet_size <= protocol::gige::GVSP_OVERHEAD {
            return Err(ctl.violation(format!(
                "stream packet size {packet_size} leaves no room for data"
            )));
        }
        ctl.write_reg(bs::SCDA0, u32::from(ip4)).await?;
        ctl.write_reg(bs::SCP0, port as u32).await?;
        // The port the camera streams from (GigE Vision 2.0; 0 or an error from an
        // older camera: then its address alone identifies its packets).
        let source_port = ctl.read_reg(bs::SCSP0).await.map_or(0, |v| v & 0xFFFF) as u16;
        let camera_stream = SocketAddr::new(addr.ip(), source_port);
        // Software trigger, continuous acquisition: one frame per TriggerSoftware.
        let set_enum = |name: &'static str, entry: &'static str| (name, entry);
        let mut settings = vec![
            set_enum("TriggerMode", "On"),
            set_enum("TriggerSource", "Software"),
        ];
        if f.xml.has("TriggerSelector") {
            settings.insert(0, set_enum("TriggerSelector", "FrameStart"));
        }
        if f.xml.has("AcquisitionMode") {
            settings.push(set_enum("AcquisitionMode", "Continuous"));
        }
        for (name, entry) in settings {
            let loc = f.reg(&device, name)?;
            let v = f
                .xml
                .enum_value(name, entry)
                .map_err(|m| DriverError::Unsupported {
                    device: device.clone(),
                    message: m,
                })?;
            write_feature(ctl, &loc, v, name).await?;
        }
        let trigger = (
            f.reg(&device, "TriggerSoftware")?,
            f.xml
                .command_value("TriggerSoftware")
                .map_err(|m| ctl.violation(m))?,
        );
        let start = f.reg(&device, "AcquisitionStart")?;
        let v = f
            .xml
            .command_value("AcquisitionStart")
            .map_err(|m| ctl.violation(m))?;
        write_feature(ctl, &start, v, "AcquisitionStart").await?;
        let exposure = ["ExposureTime", "ExposureTimeAbs"]
            .iter()
            .find_map(|n| f.xml.locate(n).ok());
        let gain = ["Gain", "GainRaw"]
            .iter()
            .find_map(|n| f.xml.locate(n).ok());
        Ok(move |ctl: Gvcp| {
            let ctl = Arc::new(tokio::sync::Mutex::new(ctl));
            let heartbeat_error = Arc::new(Mutex::new(None));
            let heartbeat = tokio::spawn(heartbeat(
                ctl.clone(),
                heartbeat_error.clone(),
                Duration::from_millis(hb_ms as u64 / 3),
            ));
            Self {
                ctl,
                stream,
                info: CameraInfo {
                    model: format!("{vendor} {model}"),
                    serial,
                    width,
                    height,
                    bit_depth,
                },
                device,
                opts,
                pixel_format,
                negotiated,
                packet_size,
                resend: caps & bs::CAP_PACKETRESEND != 0,
                trigger,
                exposure,
                gain,
                tick_hz: tick_hz.max(1),
                last_block: None,
                heartbeat_error,
                heartbeat,
                sequence: 0,
                rx: vec![0u8; 65536],
                camera_stream,
                stray: 0,
                dropped: 0,
            }
        })
    }

    /// The local address of the stream socket (where the camera sends GVSP).
    pub fn stream_addr(&self) -> std::io::Result<SocketAddr> {
        self.stream.local_addr()
    }

    /// Datagrams on the stream socket from anyone but the camera: dropped unread.
    pub fn stray_packets(&self) -> u64 {
        self.stray
    }

    /// Frames lost (incomplete, refused or never arrived) and triggered again since the
    /// camera was opened.
    pub fn dropped_frames(&self) -> u64 {
        self.dropped
    }

    /// Whether a datagram on the stream socket comes from the camera: its address,
    /// and its stream source port when the camera reports one (SCSP0).
    fn is_camera(&self, from: SocketAddr) -> bool {
        from.ip() == self.camera_stream.ip()
            && (self.camera_stream.port() == 0 || from.port() == self.camera_stream.port())
    }

    /// The stream packet size the camera accepted.
    pub fn packet_size(&self) -> u32 {
        self.packet_size
    }

    /// A leader the assembler refused (another format than negotiated at open).
    fn refused_leader(&self, block: u16, p: &Packet<'_>, e: GvspError) -> DriverError {
        let gvsp::Content::Leader(l) = p.content else {
            return DriverError::Protocol {
                device: self.device.clone(),
                message: format!("frame (block {block}): {e}; frame refused"),
            };
        };
        DriverError::Protocol {
            device: self.device.clone(),
            message: format!(
                "frame (block {block}) is {}x{} {} but the camera declared {}x{} {} at open; frame refused ({e})",
                l.width, l.height, pfnc::name(l.pixel_format),
                self.info.width, self.info.height, pfnc::name(self.pixel_format)
            ),
        }
    }

    fn incomplete(&self, a: &Assembler, why: &str) -> DriverError {
        let missing = a.missing();
        let list: Vec<String> = missing.iter().take(8).map(|m| m.to_string()).collect();
        DriverError::Protocol {
            device: self.device.clone(),
            message: format!(
                "incomplete frame (block {}): {why}; {} of {} payload packets missing (ids {}{}){}; frame refused",
                a.block_id,
                missing.len(),
                a.leader.map(|l| gvsp::payload_packets(l.payload_size(), self.packet_size)).unwrap_or(0),
                list.join(","),
                if missing.len() > 8 { ",..." } else { "" },
                if a.leader.is_none() { ", leader missing" } else { "" },
            ),
        }
    }
}

fn stream_socket(addr: SocketAddr) -> std::io::Result<UdpSocket> {
    let s = socket2::Socket::new(
        socket2::Domain::for_address(addr),
        socket2::Type::DGRAM,
        Some(socket2::Protocol::UDP),
    )?;
    // A whole frame arrives in one burst; ask for a receive buffer that holds one (the
    // kernel caps it at rmem_max; lost packets are then asked again).
    let _ = s.set_recv_buffer_size(32 << 20);
    s.set_nonblocking(true)?;
    s.bind(&addr.into())?;
    UdpSocket::from_std(s.into())
}

async fn heartbeat(
    ctl: Arc<tokio::sync::Mutex<Gvcp>>,
    error: Arc<Mutex<Option<String>>>,
    every: Duration,
) {
    let mut tick = tokio::time::interval(every);
    tick.tick().await;
    loop {
        tick.tick().await;
        let mut c = ctl.lock().await;
        let r = c.read_reg(bs::CCP).await;
        let msg = match r {
            Ok(v) if v & (bs::CCP_CONTROL | bs::CCP_EXCLUSIVE) != 0 => continue,
            Ok(v) => format!("the camera no longer grants control (CCP = 0x{v:X}): heartbeat lost"),
            Err(e) => format!("the camera stopped answering heartbeats: {e}"),
        };
        *error.lock().unwrap_or_else(|p| p.into_inner()) = Some(msg);
        return;
    }
}

/// Newer than `last` in 16-bit block ids that wrap 65535 -> 1.
fn is_newer(id: u16, last: Option<u16>) -> bool {
    match last {
        None => id != 0,
        Some(l) => id != 0 && (id.wrapping_sub(l) as i16) > 0,
    }
}

impl GigeCamera {
    /// One trigger and the frame it gives. A [`GrabFail::Frame`] lost only this frame
    /// (the next trigger gives another); a [`GrabFail::Link`] lost the camera.
    async fn grab_once(&mut self) -> Result<Frame, GrabFail> {
        if let Some(m) = self
            .heartbeat_error
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
        {
            return Err(GrabFail::Link(DriverError::Timeout {
                device: self.device.clone(),
                what: m,
                after_ms: 0,
            }));
        }
        // Packets of earlier frames (late resends) must not mix into this one.
        while let Ok((n, from)) = self.stream.try_recv_from(&mut self.rx) {
            if !self.is_camera(from) {
                self.stray += 1;
                continue;
            }
            if let Ok(p) = Packet::decode(&self.rx[..n]) {
                if is_newer(p.block_id, self.last_block) {
                    self.last_block = Some(p.block_id);
                }
            }
        }
        let (loc, v) = self.trigger.clone();
        {
            let mut c = self.ctl.lock().await;
            write_feature(&mut c, &loc, v, "TriggerSoftware")
                .await
                .map_err(|e| match e {
                    DriverError::Timeout {
                        device,
                        what,
                        after_ms,
                    } => DriverError::Timeout {
                        device,
                        what: format!("TriggerSoftware ({what})"),
                        after_ms,
                    },
                    e => e,
                })?;
        }
        let deadline = tokio::time::Instant::now() + self.opts.frame_timeout;
        let mut asm: Option<Assembler> = None;
        let mut rounds = 0;
        // Silence is counted from the camera's last packet: stray datagrams must not
        // keep a frame with holes from asking for them.
        let mut last_heard = tokio::time::Instant::now();
        loop {
            let wait = if asm.is_some() {
                deadline.min(last_heard + self.opts.packet_timeout)
            } else {
                deadline
            };
            match tokio::time::timeout_at(wait, self.stream.recv_from(&mut self.rx)).await {
                Ok(Ok((n, from))) => {
                    if !self.is_camera(from) {
                        // Anyone on the camera network can send here: never let it
                        // near the assembler (or the block id bookkeeping).
                        self.stray += 1;
                        continue;
                    }
                    last_heard = tokio::time::Instant::now();
                    let Ok(p) = Packet::decode(&self.rx[..n]) else {
                        continue;
                    };
                    if asm.is_none() {
                        if !is_newer(p.block_id, self.last_block) {
                            continue;
                        }
                        asm = Some(Assembler::new(
                            p.block_id,
                            self.packet_size,
                            self.negotiated,
                        ));
                    }
                    let a = asm.as_mut().expect("set above");
                    if let Err(e) = a.push(&p) {
                        // The camera streams another format than it declared: the
                        // rest of this block is stale from now on.
                        self.last_block = Some(a.block_id);
                        return Err(GrabFail::Frame(self.refused_leader(a.block_id, &p, e)));
                    }
                    if a.is_complete() {
                        break;
                    }
                    // The trailer with holes before it: ask for them at once; later
                    // rounds wait for silence (the resent packets are on their way).
                    let trailer =
                        matches!(p.content, protocol::gige::gvsp::Content::Trailer { .. });
                    if !(trailer && rounds == 0) {
                        continue;
                    }
                    // Trailer arrived with holes: ask for them now.
                }
                Ok(Err(e)) => {
                    return Err(GrabFail::Link(DriverError::Transport {
                        device: self.device.clone(),
                        message: format!("stream socket: {e}"),
                    }))
                }
                Err(_) => {
                    if let Some(m) = self
                        .heartbeat_error
                        .lock()
                        .unwrap_or_else(|p| p.into_inner())
                        .clone()
                    {
                        return Err(GrabFail::Link(DriverError::Timeout {
                            device: self.device.clone(),
                            what: m,
                            after_ms: 0,
                        }));
                    }
                    let Some(a) = &asm else {
                        return Err(GrabFail::Frame(DriverError::Timeout {
                            device: self.device.clone(),
                            what: "a frame after TriggerSoftware (no stream packet arrived)".into(),
                            after_ms: self.opts.frame_timeout.as_millis() as u64,
                        }));
                    };
                    if a.is_complete() {
                        break;
                    }
                    if tokio::time::Instant::now() >= deadline {
                        return Err(GrabFail::Frame(self.incomplete(a, "frame timeout")));
                    }
                }
            }
            let a = asm.as_ref().expect("a frame has started");
            if !self.resend || rounds >= self.opts.resend_rounds {
                let why = if self.resend {
                    "packets still missing after resend requests"
                } else {
                    "packets lost and the camera cannot resend"
                };
                let e = self.incomplete(a, why);
                self.last_block = Some(a.block_id);
                return Err(GrabFail::Frame(e));
            }
            rounds += 1;
            let missing = a.missing();
            let block = a.block_id;
            let mut c = self.ctl.lock().await;
            if a.leader.is_none() {
                c.packet_resend(block, 0, 0).await?;
            }
            for (first, last) in ranges(&missing) {
                c.packet_resend(block, first, last).await?;
            }
            // Give the resent packets their packet timeout.
            last_heard = tokio::time::Instant::now();
        }
        let a = asm.expect("complete");
        let block = a.block_id;
        self.last_block = Some(block);
        let (leader, data) = a.into_data().expect("complete");
        if leader.width != self.info.width
            || leader.height != self.info.height
            || leader.pixel_format != self.pixel_format
        {
            return Err(GrabFail::Frame(DriverError::Protocol {
                device: self.device.clone(),
                message: format!(
                    "frame (block {block}) is {}x{} {} but the camera declared {}x{} {} at open; frame refused",
                    leader.width, leader.height, pfnc::name(leader.pixel_format),
                    self.info.width, self.info.height, pfnc::name(self.pixel_format)
                ),
            }));
        }
        let pixels = match leader.pixel_format {
            pfnc::MONO8 => Pixels::Mono8(data),
            _ => Pixels::Mono16(
                data.chunks_exact(2)
                    .map(|c| u16::from_le_bytes([c[0], c[1]]))
                    .collect(),
            ),
        };
        let image = MonoImage::new(leader.width, leader.height, pixels).map_err(|e| {
            GrabFail::Frame(DriverError::Protocol {
                device: self.device.clone(),
                message: format!("frame (block {block}): {e}"),
            })
        })?;
        let (exposure_us, gain_db) = {
            let mut c = self.ctl.lock().await;
            let e = match &self.exposure {
                Some(l) => read_float(&mut c, l).await.unwrap_or(f64::NAN),
                None => f64::NAN,
            };
            let g = match &self.gain {
                Some(l) => read_float(&mut c, l).await.unwrap_or(f64::NAN),
                None => f64::NAN,
            };
            (e, g)
        };
        let meta = FrameMeta {
            sequence: self.sequence,
            timestamp_ns: (leader.timestamp as u128 * 1_000_000_000 / self.tick_hz as u128) as u64,
            exposure_us,
            gain_db,
        };
        self.sequence += 1;
        Ok(Frame { image, meta })
    }
}

/// Why one grab attempt failed.
enum GrabFail {
    /// This frame is lost (incomplete, refused, never arrived); the stream goes on.
    Frame(DriverError),
    /// The camera or its control channel is lost: no retry helps.
    Link(DriverError),
}

impl From<DriverError> for GrabFail {
    fn from(e: DriverError) -> Self {
        GrabFail::Link(e)
    }
}

/// How many triggers one grab may use: a frame lost (packets lost for good, a leader
/// refused, a forged datagram in the way, no packet at all) is dropped and the camera
/// triggered again, as Aravis drops a bad buffer and keeps streaming; only when this
/// many frames in a row are lost does the grab fail (the job then stops). A lost link
/// (heartbeat, control channel, socket) fails at once.
pub const GRAB_ATTEMPTS: u32 = 3;

#[async_trait]
impl Camera for GigeCamera {
    fn info(&self) -> &CameraInfo {
        &self.info
    }

    async fn grab(&mut self) -> Result<Frame, DriverError> {
        let mut attempt = 1;
        loop {
            match self.grab_once().await {
                Ok(f) => return Ok(f),
                Err(GrabFail::Link(e)) => return Err(e),
                Err(GrabFail::Frame(e)) => {
                    self.dropped += 1;
                    if attempt >= GRAB_ATTEMPTS {
                        let note = format!(
                            " ({GRAB_ATTEMPTS} frames in a row lost; {} dropped since open)",
                            self.dropped
                        );
                        return Err(match e {
                            DriverError::Protocol { device, message } => DriverError::Protocol {
                                device,
                                message: message + &note,
                            },
                            DriverError::Timeout {
                                device,
                                what,
                                after_ms,
                            } => DriverError::Timeout {
                                device,
                                what: what + &note,
                                after_ms,
                            },
                            e => e,
                        });
                    }
                    attempt += 1;
                }
            }
        }
    }
}

/// Contiguous runs of packet ids.
fn ranges(ids: &[u32]) -> Vec<(u32, u32)> {
    let mut out: Vec<(u32, u32)> = Vec::new();
    for &i in ids {
        match out.last_mut() {
            Some((_, l)) if *l + 1 == i => *l = i,
            _ => out.push((i, i)),
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bit_fields_of_any_width_never_overflow() {
        assert_eq!(field_value(0xABCD, Some((4, 8))), 0xBC);
        assert_eq!(field_value(u64::MAX, Some((0, 64))), u64::MAX);
        assert_eq!(field_value(u64::MAX, Some((63, 1))), 1);
        assert_eq!(merge_field(0xFFFF_0000, 0x5, (4, 4)), 0xFFFF_0050);
        assert_eq!(merge_field(0, u32::MAX, (0, 32)), u32::MAX);
        // Fields a Location could hold though `locate` never makes them.
        for f in [(64, 1), (0, 0), (0, 65), (200, 200), (u32::MAX, u32::MAX)] {
            let r =
                std::panic::catch_unwind(|| (field_value(u64::MAX, Some(f)), merge_field(1, 1, f)));
            assert!(r.is_ok(), "{f:?} panicked");
        }
    }

    #[test]
    fn block_ids_wrap_and_runs_group() {
        assert!(is_newer(1, None));
        assert!(!is_newer(0, None));
        assert!(is_newer(5, Some(4)));
        assert!(!is_newer(4, Some(4)));
        assert!(!is_newer(3, Some(4)));
        assert!(is_newer(1, Some(65535)));
        assert_eq!(ranges(&[1, 2, 3, 7, 9, 10]), vec![(1, 3), (7, 7), (9, 10)]);
    }
}
