//! The GigE Vision camera served over UDP: GVCP on a control socket (port 3956 for
//! stand-alone use, where Aravis discovery looks; port 0 on loopback in tests so that
//! parallel tests never collide), GVSP from a stream socket to the host and port the
//! controller wrote into SCDA0/SCP0, in packets of the SCPS0 size. Every frame is
//! rendered from the shared [`SimRig`] at the moment of the trigger (or at each tick of
//! the frame rate in continuous mode), so a move over any stage link shows in the next
//! frame. The last frame is kept for PACKETRESEND.

use super::device::{Event, GigeConfig, GigeDevice};
use protocol::gige::gvsp::{self, ImageLeader};
use protocol::Pixels;
use std::net::{IpAddr, Ipv4Addr, SocketAddr};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use tokio::net::UdpSocket;
use tokio::task::JoinHandle;
use tokio::time::Instant;
use world::lock;
use world::rig::SimRig;

/// Where and how to serve.
#[derive(Clone, Debug)]
pub struct GigeServerOptions {
    /// Control socket address; `127.0.0.1:0` picks a free port.
    pub bind: SocketAddr,
    /// Also receive discovery broadcasts (255.255.255.255:<port>), as Aravis's
    /// enumeration sends them; needs a fixed port (3956).
    pub broadcast: bool,
    pub config: GigeConfig,
}

impl Default for GigeServerOptions {
    fn default() -> Self {
        Self {
            bind: SocketAddr::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 0),
            broadcast: false,
            config: GigeConfig::default(),
        }
    }
}

/// A running emulated camera; stops when dropped.
pub struct GigeCameraServer {
    addr: SocketAddr,
    silent: Arc<AtomicBool>,
    frames: Arc<AtomicU64>,
    frames_tx: tokio::sync::watch::Receiver<u64>,
    task: JoinHandle<()>,
}

impl Drop for GigeCameraServer {
    fn drop(&mut self) {
        self.task.abort();
    }
}

fn udp(addr: SocketAddr, reuse: bool) -> std::io::Result<UdpSocket> {
    let s = socket2::Socket::new(
        socket2::Domain::for_address(addr),
        socket2::Type::DGRAM,
        Some(socket2::Protocol::UDP),
    )?;
    if reuse {
        s.set_reuse_address(true)?;
    }
    s.set_broadcast(true)?;
    // Whole frames leave in one burst; a large send buffer keeps them from being dropped
    // locally (the kernel caps the value at wmem_max).
    let _ = s.set_send_buffer_size(8 << 20);
    s.set_nonblocking(true)?;
    s.bind(&addr.into())?;
    UdpSocket::from_std(s.into())
}

impl GigeCameraServer {
    /// Binds the sockets and starts serving frames of `rig` (inside a tokio runtime).
    pub async fn spawn(rig: Arc<Mutex<SimRig>>, opts: GigeServerOptions) -> std::io::Result<Self> {
        // No address reuse on the control socket: a second device on the same port must
        // fail to start, not silently share its datagrams.
        let control = udp(opts.bind, false)?;
        let addr = control.local_addr()?;
        let bcast = if opts.broadcast {
            Some(udp(
                SocketAddr::new(IpAddr::V4(Ipv4Addr::BROADCAST), addr.port()),
                true,
            )?)
        } else {
            None
        };
        let stream = udp(SocketAddr::new(addr.ip(), 0), false)?;
        let ip = match addr.ip() {
            IpAddr::V4(ip) if !ip.is_unspecified() => ip,
            _ => Ipv4Addr::LOCALHOST,
        };
        let (w, h, depth) = {
            let r = lock(&rig);
            (r.camera().width, r.camera().height, r.camera().bit_depth)
        };
        let mut device = GigeDevice::new(opts.config, w, h, depth, ip);
        device.set_stream_source_port(stream.local_addr()?.port());
        let silent = Arc::new(AtomicBool::new(false));
        let frames = Arc::new(AtomicU64::new(0));
        let (frames_tx, frames_rx) = tokio::sync::watch::channel(0u64);
        let srv = Server {
            rig,
            device,
            control,
            bcast,
            stream,
            silent: silent.clone(),
            frames: frames.clone(),
            frames_tx,
            start: Instant::now(),
            block_id: 0,
            last: None,
            next_tick: None,
            rendering: None,
            exposure_ticks: None,
            queued: 0,
            buf: Vec::with_capacity(66_000),
        };
        let task = tokio::spawn(srv.run());
        Ok(Self {
            addr,
            silent,
            frames,
            frames_tx: frames_rx,
            task,
        })
    }

    /// The GVCP address clients connect to.
    pub fn control_addr(&self) -> SocketAddr {
        self.addr
    }

    /// Makes the camera stop answering (a dead or unplugged camera) or answer again.
    pub fn set_silent(&self, silent: bool) {
        self.silent.store(silent, Ordering::SeqCst);
    }

    /// Follows the number of frames streamed (to await a count without polling).
    pub fn frames_watch(&self) -> tokio::sync::watch::Receiver<u64> {
        self.frames_tx.clone()
    }

    /// Frames streamed so far.
    pub fn frames_sent(&self) -> u64 {
        self.frames.load(Ordering::SeqCst)
    }
}

struct LastFrame {
    block_id: u16,
    leader: ImageLeader,
    data: Vec<u8>,
    packet_size: u32,
    dest: SocketAddr,
}

struct Server {
    rig: Arc<Mutex<SimRig>>,
    device: GigeDevice,
    control: UdpSocket,
    bcast: Option<UdpSocket>,
    stream: UdpSocket,
    silent: Arc<AtomicBool>,
    frames: Arc<AtomicU64>,
    frames_tx: tokio::sync::watch::Sender<u64>,
    start: Instant,
    block_id: u16,
    last: Option<LastFrame>,
    /// Next continuous-mode frame.
    next_tick: Option<Instant>,
    /// The frame being rendered (off the control loop, so GVCP stays responsive while a
    /// large frame renders) and the triggers that arrived meanwhile.
    rendering: Option<JoinHandle<(protocol::MonoImage, world::rig::SimFrameInfo)>>,
    /// Timestamp (device ticks) of the frame being rendered, latched at its trigger.
    exposure_ticks: Option<u64>,
    queued: u32,
    buf: Vec<u8>,
}

async fn rendered(
    r: &mut Option<JoinHandle<(protocol::MonoImage, world::rig::SimFrameInfo)>>,
) -> Option<(protocol::MonoImage, world::rig::SimFrameInfo)> {
    match r {
        Some(h) => h.await.ok(),
        None => std::future::pending().await,
    }
}

async fn recv_opt(s: &Option<UdpSocket>, buf: &mut [u8]) -> std::io::Result<(usize, SocketAddr)> {
    match s {
        Some(s) => s.recv_from(buf).await,
        None => std::future::pending().await,
    }
}

async fn sleep_opt(at: Option<Instant>) {
    match at {
        Some(t) => tokio::time::sleep_until(t).await,
        None => std::future::pending().await,
    }
}

impl Server {
    fn now_ms(&self) -> u64 {
        self.start.elapsed().as_millis() as u64
    }

    async fn run(mut self) {
        let mut rx = vec![0u8; 2048];
        let mut rx2 = vec![0u8; 2048];
        loop {
            let hb = self
                .device
                .heartbeat_deadline_ms()
                .map(|ms| self.start + std::time::Duration::from_millis(ms));
            let (datagram, from, via_bcast) = tokio::select! {
                r = self.control.recv_from(&mut rx) => match r {
                    Ok((n, from)) => (rx[..n].to_vec(), from, false),
                    Err(_) => continue,
                },
                r = recv_opt(&self.bcast, &mut rx2) => match r {
                    Ok((n, from)) => (rx2[..n].to_vec(), from, true),
                    Err(_) => continue,
                },
                f = rendered(&mut self.rendering) => {
                    self.rendering = None;
                    if let Some((image, info)) = f {
                        self.stream_frame(image, info).await;
                    }
                    if self.queued > 0 {
                        self.queued -= 1;
                        self.start_render();
                    }
                    continue;
                }
                _ = sleep_opt(self.next_tick) => {
                    self.continuous_tick().await;
                    continue;
                }
                _ = sleep_opt(hb) => {
                    let ev = self.device.poll(self.now_ms());
                    self.act(ev).await;
                    continue;
                }
            };
            if self.silent.load(Ordering::SeqCst) {
                continue;
            }
            let _ = via_bcast;
            let (ack, events) = self.device.handle(from, self.now_ms(), &datagram);
            if let Some(ack) = ack {
                // Replies always leave from the control socket (the unicast address the
                // client must talk to afterwards).
                let _ = self.control.send_to(&ack, from).await;
            }
            self.act(events).await;
        }
    }

    async fn act(&mut self, events: Vec<Event>) {
        for e in events {
            match e {
                Event::AcquisitionStarted => {
                    if !self.device.software_triggered() {
                        if self.device.acquisition_mode() == 1 {
                            self.start_render();
                        } else {
                            self.next_tick = Some(Instant::now());
                        }
                    }
                }
                Event::AcquisitionStopped | Event::ControlReleased => self.next_tick = None,
                Event::Trigger => self.start_render(),
                Event::Resend {
                    block_id,
                    first,
                    last,
                } => self.resend(block_id, first, last).await,
            }
        }
    }

    async fn continuous_tick(&mut self) {
        if !self.device.acquiring() || self.device.software_triggered() {
            self.next_tick = None;
            return;
        }
        if self.silent.load(Ordering::SeqCst) {
            self.next_tick = None;
            return;
        }
        // A frame still rendering is not queued behind: this tick is skipped.
        if self.rendering.is_none() {
            self.start_render();
        }
        let period = std::time::Duration::from_secs_f32(1.0 / self.device.frame_rate_hz());
        let next = self.next_tick.unwrap_or_else(Instant::now) + period;
        // Never queue up frames behind a slow render: skip to the next period from now.
        self.next_tick = Some(next.max(Instant::now()));
    }

    /// Exposes a frame now: the rig is read at this moment (the trigger), rendered on
    /// the blocking pool.
    fn start_render(&mut self) {
        if self.device.stream_destination().is_none() {
            return;
        }
        if self.rendering.is_some() {
            self.queued += 1;
            return;
        }
        // The timestamp is latched at the trigger, from the device clock.
        self.exposure_ticks = match self.device.config().clock {
            world::Clock::Scaled(k) => Some((self.start.elapsed().as_secs_f64() * 1e9 * k) as u64),
            world::Clock::Unconstrained => None,
        };
        let rig = self.rig.clone();
        self.rendering = Some(tokio::task::spawn_blocking(move || lock(&rig).grab()));
    }

    async fn stream_frame(&mut self, image: protocol::MonoImage, info: world::rig::SimFrameInfo) {
        let Some(dest) = self.device.stream_destination() else {
            return;
        };
        // The leader describes what was rendered (a camera reconfigured behind the
        // client's back sends what it now is; the client must notice).
        let pixel_format = match image.pixels {
            Pixels::Mono8(_) => protocol::gige::pfnc::MONO8,
            Pixels::Mono16(_) => protocol::gige::pfnc::MONO16,
        };
        let data = match image.pixels {
            Pixels::Mono8(p) => p,
            // PFNC Mono16 is little-endian on the wire unless SCPS bit 29 is set.
            Pixels::Mono16(p) => p.iter().flat_map(|v| v.to_le_bytes()).collect(),
        };
        self.block_id = if self.block_id == u16::MAX {
            1
        } else {
            self.block_id + 1
        };
        let leader = ImageLeader {
            // Device clock at the trigger; unconstrained: the simulated machine's.
            timestamp: self
                .exposure_ticks
                .unwrap_or_else(|| (info.time_s * 1e9).round() as u64),
            pixel_format,
            width: image.width,
            height: image.height,
            offset_x: 0,
            offset_y: 0,
        };
        let frame = LastFrame {
            block_id: self.block_id,
            leader,
            data,
            packet_size: self.device.packet_size(),
            dest,
        };
        let n = gvsp::payload_packets(frame.data.len(), frame.packet_size);
        let drop_every = self.device.config().drop_every;
        for id in 0..=n + 1 {
            let lost = matches!(drop_every, Some(k) if k > 0 && id >= 1 && id <= n && id % k == 0);
            if !lost {
                self.send_packet(&frame, id).await;
            }
        }
        self.last = Some(frame);
        let n = self.frames.fetch_add(1, Ordering::SeqCst) + 1;
        self.frames_tx.send_replace(n);
    }

    async fn send_packet(&mut self, f: &LastFrame, id: u32) {
        if gvsp::encode_frame_packet(
            f.block_id,
            &f.leader,
            &f.data,
            f.packet_size,
            id,
            &mut self.buf,
        ) {
            // A full socket buffer or unreachable host loses the packet, as on a wire.
            let _ = self.stream.send_to(&self.buf, f.dest).await;
        }
    }

    async fn resend(&mut self, block_id: u16, first: u32, last: u32) {
        let Some(f) = self.last.take() else {
            return;
        };
        if f.block_id == block_id && !self.device.config().loss_on_resend {
            let n = gvsp::payload_packets(f.data.len(), f.packet_size);
            for id in first..=last.min(n + 1) {
                self.send_packet(&f, id).await;
            }
        }
        self.last = Some(f);
    }
}
