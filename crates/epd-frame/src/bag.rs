//! A ROS 2 bag's `sensor_msgs/msg/PointCloud2` messages measured one by one, as
//! [`crate::measure_file`] measures a file: the bag read by `epd_io::bag` (streamed, one
//! message decoded at a time), each cloud converted to metres in the sensor frame in the
//! frame its `frame_id` says ([`InputConfig::frame_of`](crate::InputConfig::frame_of)),
//! then [`crate::measure::measure_cloud`]. One [`FileReport`] per message, in order, with
//! its `stamp_ns` and `frame_id`; a damaged bag ends with a report of the damage.
//!
//! The caller drives the iteration ([`BagFrames`]): it decides how many messages are
//! measured at once (the `epd` tool measures a few in parallel), so memory stays bounded
//! by those few messages, whatever the bag's length.

use std::path::{Path, PathBuf};
use std::time::Instant;

pub use epd_io::bag::{
    BagClouds, BagError, BagMessage, MCAP_MAGIC, ODOMETRY, OdometryPosition, OdometryTrack,
    POINT_CLOUD2, PointCloud2, TopicInfo, Topics, bag_files, decode_odometry, decode_point_cloud2,
    is_bag, odometry, topics,
};

use crate::config::EstimateConfig;
use crate::input::to_sensor_metres;
use crate::measure::measure_cloud;
use crate::report::{FileReport, MessageSource};

/// One message taken from a bag, decoded, not yet measured.
#[derive(Clone, Debug)]
pub struct BagFrame {
    /// The bag as given.
    pub bag: PathBuf,
    /// The topic.
    pub topic: String,
    /// The message.
    pub message: BagMessage,
    /// The time taken to read and decode it (ms), reported as `read_ms`.
    pub read_ms: f64,
}

/// The messages of one topic of a bag, decoded one at a time ([`BagClouds`]), each with
/// its reading time; a damaged bag's last item is the [`BagError`] (as a report, see
/// [`damage_report`]).
pub struct BagFrames {
    bag: PathBuf,
    clouds: BagClouds,
}

impl BagFrames {
    /// Open `bag` for the messages of `topic` (see [`Topics::choose`]).
    pub fn open(bag: &Path, topic: &str) -> Result<BagFrames, BagError> {
        Ok(BagFrames {
            bag: bag.to_path_buf(),
            clouds: BagClouds::open(bag, topic)?,
        })
    }

    /// Only the messages whose index lies in `keep` ([`BagClouds::only`]): the others are
    /// skipped undecoded.
    pub fn only(self, keep: std::ops::Range<u64>) -> BagFrames {
        BagFrames {
            bag: self.bag,
            clouds: self.clouds.only(keep),
        }
    }
}

impl Iterator for BagFrames {
    type Item = Result<BagFrame, BagError>;

    fn next(&mut self) -> Option<Self::Item> {
        let t0 = Instant::now();
        let message = self.clouds.next()?;
        let read_ms = t0.elapsed().as_secs_f64() * 1e3;
        Some(message.map(|message| BagFrame {
            bag: self.bag.clone(),
            topic: self.clouds.topic().to_string(),
            message,
            read_ms,
        }))
    }
}

/// Measure one message: its points converted to metres in the sensor frame (the frame
/// from `frame_id` unless one was given), then [`measure_cloud`].
pub fn measure_message(frame: BagFrame, cfg: &EstimateConfig) -> FileReport {
    let BagFrame {
        bag,
        topic,
        message,
        read_ms,
    } = frame;
    let (stamp_ns, frame_id) = match &message.cloud {
        Ok(c) => (Some(c.stamp_ns), Some(c.frame_id.clone())),
        Err(_) => (None, None),
    };
    let outcome = message
        .cloud
        .map_err(|e| format!("message {}: {e}", message.index))
        .and_then(|c| {
            let mut cloud = c.cloud;
            let frame = cfg.input.frame_of(&c.frame_id);
            to_sensor_metres(&mut cloud.points, cfg.input.units, frame)?;
            measure_cloud(cloud, read_ms, cfg)
        });
    let mut r = FileReport::of_path(&bag, outcome);
    r.message = Some(MessageSource {
        topic,
        index: message.index,
        stamp_ns,
        frame_id,
    });
    r
}

/// The report of a bag that could not be read on: its error, after the messages read.
pub fn damage_report(bag: &Path, e: &BagError) -> FileReport {
    FileReport::of_path(bag, Err(e.to_string()))
}

#[cfg(test)]
mod tests {
    use crate::{InputConfig, InputFrame, Units};

    /// An `_optical_frame` is read as the optical frame unless a frame was given; other
    /// frame ids take the frame given (the sensor frame by default).
    #[test]
    fn optical_frame_ids_unless_a_frame_is_given() {
        let mut input = InputConfig {
            units: Units::Metres,
            frame: InputFrame::Sensor,
            frame_given: false,
            format: None,
        };
        assert_eq!(
            input.frame_of("camera_depth_optical_frame"),
            InputFrame::Optical
        );
        assert_eq!(input.frame_of("camera_link"), InputFrame::Sensor);
        input.frame = InputFrame::Body;
        input.frame_given = true;
        assert_eq!(
            input.frame_of("camera_depth_optical_frame"),
            InputFrame::Body
        );
        assert_eq!(input.frame_of("base_link"), InputFrame::Body);
    }
}
