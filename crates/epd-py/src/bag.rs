//! `epd.read_bag`: the PointCloud2 messages of a ROS 2 bag, one at a time.

use super::*;

/// The PointCloud2 messages of one topic of a ROS 2 bag (an `.mcap` file or a rosbag2
/// folder with `metadata.yaml`), read as `epd estimate BAG --topic T` reads them.
///
/// Iterating yields `(stamp_ns, points, properties)` per message, in the bag's order:
/// `stamp_ns` the message's `header.stamp` (int, ns), `points` an (N, 3) float64 array as
/// stored in the message (not converted: pass `units=`/`frame=` to `estimate`; a
/// `frame_id` ending in `_optical_frame` means `frame="optical"`), `properties` a dict of
/// the other fields with count 1 (`intensity`, …) as float64 arrays; the iterator's
/// `frame_id` is the last message's `header.frame_id`. One message is in
/// memory at a time. `topic=None` reads the bag's only PointCloud2 topic. Raises
/// `ValueError` for a topic that cannot be chosen, a message that cannot be decoded, or
/// a truncated or damaged bag (after the messages before the damage were yielded, naming
/// its byte offset), and `OSError` for a bag that cannot be opened.
#[pyfunction]
#[pyo3(signature = (path, topic=None))]
pub(crate) fn read_bag(path: PathBuf, topic: Option<&str>) -> PyResult<BagReader> {
    use epd_frame::bag::{BagClouds, BagError, topics};
    let fail = |e: BagError| match e {
        BagError::Open(m) => file_error(&path, m),
        other => PyValueError::new_err(other.to_string()),
    };
    let chosen = topics(&path)
        .map_err(fail)?
        .choose(topic)
        .map_err(|e| PyValueError::new_err(e.to_string().replace("--topic", "topic=")))?;
    let clouds = BagClouds::open(&path, &chosen).map_err(fail)?;
    Ok(BagReader {
        clouds,
        frame_id: None,
    })
}

/// One message as `read_bag` yields it: `(stamp_ns, points, properties)`.
type BagItem<'py> = (i64, Bound<'py, PyAny>, Bound<'py, PyDict>);

/// The iterator `read_bag` returns: `(stamp_ns, points, properties)` per message.
#[pyclass(unsendable, module = "epd")]
pub(crate) struct BagReader {
    clouds: epd_frame::bag::BagClouds,
    /// The `frame_id` of the message yielded last (`None` before the first).
    #[pyo3(get)]
    frame_id: Option<String>,
}

#[pymethods]
impl BagReader {
    fn __iter__(slf: PyRef<'_, Self>) -> PyRef<'_, Self> {
        slf
    }

    fn __next__<'py>(&mut self, py: Python<'py>) -> PyResult<Option<BagItem<'py>>> {
        let Some(next) = self.clouds.next() else {
            return Ok(None);
        };
        let m = next.map_err(|e| PyValueError::new_err(e.to_string()))?;
        let c = m
            .cloud
            .map_err(|e| PyValueError::new_err(format!("message {}: {e}", m.index)))?;
        let props = PyDict::new(py);
        for (name, v) in c.cloud.extra {
            props.set_item(name, PyArray1::from_vec(py, v))?;
        }
        self.frame_id = Some(c.frame_id);
        Ok(Some((c.stamp_ns, points_array(py, c.cloud.points)?, props)))
    }
}
