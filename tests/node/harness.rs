//! Set-up shared by the live-node tests: a loopback domain, a rendered frame, and a client
//! that plays the cameras.

use mode360::frame::RigFrame;
use mode360::geometry::Rig;
use mode360::msgs::image::image_msg_from_rgb;
use mode360::msgs::{Header, Image};
use mode360::node::{create_publisher, sensor_qos, DdsOptions, SpunNode};
use mode360::synth::{SynthConfig, SynthRenderer};
use ros2_client::Publisher;
use std::time::{Duration, Instant};

/// How long to wait for the node to subscribe to the cameras.
const DISCOVERY_TIMEOUT: Duration = Duration::from_secs(10);
const POLL: Duration = Duration::from_millis(20);

/// DDS on loopback only, in `domain_id`.
pub fn loopback(domain_id: u16) -> DdsOptions {
    DdsOptions {
        domain_id,
        loopback_only: true,
    }
}

/// Frame 0 of a street rendered with `seed` at `width` on `rig`.
pub fn render(rig: &Rig, seed: u64, width: usize) -> Result<RigFrame, Box<dyn std::error::Error>> {
    Ok(SynthRenderer::new(SynthConfig {
        seed,
        width,
        ..Default::default()
    })?
    .render_frame(rig, 0))
}

/// One best-effort image publisher per rig camera on a client node, sending one frame's
/// images again and again under increasing stamps.
pub struct Cameras {
    pubs: Vec<Publisher<Image>>,
    rig: Rig,
    frame: RigFrame,
    stamp_ns: u64,
    step_ns: u64,
}

impl Cameras {
    /// Creates the publishers on `client` and waits (up to 10 s) until the node subscribed
    /// to every one.
    pub fn new(
        client: &mut SpunNode,
        rig: &Rig,
        frame: RigFrame,
        step_ns: u64,
    ) -> Result<Self, Box<dyn std::error::Error>> {
        let pubs = rig
            .cameras
            .iter()
            .map(|c| create_publisher::<Image>(&mut client.node, &c.topic, sensor_qos()))
            .collect::<Result<Vec<_>, _>>()?;
        let t0 = Instant::now();
        while pubs
            .iter()
            .any(|p| p.get_subscription_count(&client.node) == 0)
            && t0.elapsed() < DISCOVERY_TIMEOUT
        {
            std::thread::sleep(POLL);
        }
        Ok(Self {
            pubs,
            rig: rig.clone(),
            stamp_ns: frame.stamp_ns,
            frame,
            step_ns,
        })
    }

    /// Sends the images of cameras `cams` under the next stamp; returns the stamp.
    pub fn send(&mut self, cams: &[usize]) -> Result<u64, String> {
        self.stamp_ns += self.step_ns;
        for &i in cams {
            let msg = image_msg_from_rgb(
                Header::new(self.stamp_ns, &self.rig.cameras[i].frame_id),
                &self.frame.images[i],
            );
            self.pubs[i].publish(msg).map_err(|e| format!("{e:?}"))?;
        }
        Ok(self.stamp_ns)
    }

    /// Sends every camera's image under the next stamp.
    pub fn send_all(&mut self) -> Result<u64, String> {
        let all: Vec<usize> = (0..self.pubs.len()).collect();
        self.send(&all)
    }
}
