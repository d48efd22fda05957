//! A deliberately small RTDE client for the mock's tests, written on the sans-IO codec, so the
//! tests do not depend on the rig's own client.

use std::net::SocketAddr;
use std::time::Duration;

use bytes::BytesMut;
use rig_core::rtde::{
    ClientPackage, FieldType, FrameDecoder, PROTOCOL_V2, ServerPackage, Value, decode_values,
    encode_values,
};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio::net::TcpStream;

/// Real-time limit for any single expected reply.
pub const REPLY_TIMEOUT: Duration = Duration::from_secs(5);

pub struct RawClient {
    pub sock: TcpStream,
    pub decoder: FrameDecoder,
    pub version: u16,
}

impl RawClient {
    pub async fn connect(addr: SocketAddr) -> Self {
        let sock = TcpStream::connect(addr).await.expect("connect to the mock");
        sock.set_nodelay(true).unwrap();
        Self {
            sock,
            decoder: FrameDecoder::new(),
            version: 1,
        }
    }

    pub async fn send(&mut self, pkg: ClientPackage) {
        let mut out = BytesMut::new();
        pkg.encode(self.version, &mut out).unwrap();
        self.sock.write_all(&out).await.unwrap();
    }

    pub async fn send_raw(&mut self, bytes: &[u8]) {
        self.sock.write_all(bytes).await.unwrap();
    }

    /// Next package, or `None` after `within` of real time or at EOF.
    pub async fn recv_within(&mut self, within: Duration) -> Option<ServerPackage> {
        let deadline = tokio::time::Instant::now() + within;
        loop {
            if let Some(f) = self.decoder.next_frame().expect("server framing") {
                return Some(ServerPackage::decode(&f, self.version).expect("server package"));
            }
            let n =
                tokio::time::timeout_at(deadline, self.sock.read_buf(self.decoder.buffer_mut()))
                    .await
                    .ok()?
                    .ok()?;
            if n == 0 {
                return None;
            }
        }
    }

    pub async fn recv(&mut self) -> ServerPackage {
        self.recv_within(REPLY_TIMEOUT)
            .await
            .expect("a reply from the mock in time")
    }

    /// Next package that is not a text message.
    pub async fn recv_reply(&mut self) -> ServerPackage {
        loop {
            match self.recv().await {
                ServerPackage::TextMessage(_) => continue,
                p => return p,
            }
        }
    }

    /// V (requested version) and v; returns the controller version.
    pub async fn handshake(&mut self, version: u16) -> (u32, u32, u32, u32) {
        self.send(ClientPackage::RequestProtocolVersion(version))
            .await;
        assert_eq!(
            self.recv_reply().await,
            ServerPackage::ProtocolVersion { accepted: true }
        );
        self.version = version;
        self.send(ClientPackage::GetUrControlVersion).await;
        match self.recv_reply().await {
            ServerPackage::UrControlVersion {
                major,
                minor,
                bugfix,
                build,
            } => (major, minor, bugfix, build),
            other => panic!("expected a controller version, got {other:?}"),
        }
    }

    pub async fn setup_outputs(&mut self, hz: f64, names: &[&str]) -> (Option<u8>, Vec<FieldType>) {
        self.send(ClientPackage::SetupOutputs {
            frequency_hz: hz,
            names: names.iter().map(|s| s.to_string()).collect(),
        })
        .await;
        match self.recv_reply().await {
            ServerPackage::OutputSetup { recipe_id, types } => (recipe_id, types),
            other => panic!("expected an output setup reply, got {other:?}"),
        }
    }

    pub async fn setup_inputs(&mut self, names: &[&str]) -> (u8, Vec<FieldType>) {
        self.send(ClientPackage::SetupInputs {
            names: names.iter().map(|s| s.to_string()).collect(),
        })
        .await;
        match self.recv_reply().await {
            ServerPackage::InputSetup { recipe_id, types } => (recipe_id, types),
            other => panic!("expected an input setup reply, got {other:?}"),
        }
    }

    pub async fn start(&mut self) -> bool {
        self.send(ClientPackage::Start).await;
        match self.recv_reply().await {
            ServerPackage::StartReply { accepted } => accepted,
            other => panic!("expected a start reply, got {other:?}"),
        }
    }

    pub async fn write_inputs(&mut self, recipe_id: u8, values: &[Value]) {
        let mut payload = BytesMut::new();
        encode_values(values, &mut payload);
        self.send(ClientPackage::Data {
            recipe_id,
            payload: payload.freeze(),
        })
        .await;
    }

    /// Exactly `n` data packages: waits (real time, generously) for `n`, then checks that no
    /// further one follows within `quiet`.
    pub async fn collect_exactly(
        &mut self,
        types: &[FieldType],
        n: usize,
        quiet: Duration,
    ) -> Vec<Vec<Value>> {
        let mut rows = Vec::new();
        while rows.len() < n {
            let got = self
                .collect_data_until(types, n - rows.len(), REPLY_TIMEOUT)
                .await;
            assert!(
                !got.is_empty(),
                "only {} of {n} data packages arrived",
                rows.len()
            );
            rows.extend(got);
        }
        let extra = self.collect_data(types, quiet).await;
        assert!(
            extra.is_empty(),
            "{} data packages more than {n}",
            extra.len()
        );
        rows
    }

    async fn collect_data_until(
        &mut self,
        types: &[FieldType],
        max: usize,
        within: Duration,
    ) -> Vec<Vec<Value>> {
        let types: Vec<_> = types
            .iter()
            .map(|t| match t {
                FieldType::Known(t) => *t,
                other => panic!("recipe has {other:?}"),
            })
            .collect();
        let mut out = Vec::new();
        while out.len() < max {
            match self.recv_within(within).await {
                Some(ServerPackage::Data { payload, .. }) => {
                    out.push(decode_values(&types, &payload).expect("data matches the recipe"))
                }
                Some(_) => {}
                None => break,
            }
        }
        out
    }

    /// Every data package that arrives until the line has been quiet for `quiet` (real time),
    /// decoded with `types`.
    pub async fn collect_data(&mut self, types: &[FieldType], quiet: Duration) -> Vec<Vec<Value>> {
        let types: Vec<_> = types
            .iter()
            .map(|t| match t {
                FieldType::Known(t) => *t,
                other => panic!("recipe has {other:?}"),
            })
            .collect();
        let mut out = Vec::new();
        while let Some(p) = self.recv_within(quiet).await {
            if let ServerPackage::Data { payload, recipe_id } = p {
                if self.version >= PROTOCOL_V2 {
                    assert!(recipe_id.is_some());
                }
                out.push(decode_values(&types, &payload).expect("data matches the recipe"));
            }
        }
        out
    }
}

/// Poll `cond` on real time until it holds (a mock task has run), failing after 5 s.
pub async fn eventually(what: &str, mut cond: impl FnMut() -> bool) {
    let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
    while !cond() {
        assert!(
            tokio::time::Instant::now() < deadline,
            "timed out waiting for {what}"
        );
        tokio::time::sleep(Duration::from_millis(1)).await;
    }
}
