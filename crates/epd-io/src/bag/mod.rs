//! ROS 2 bags in MCAP storage: the `sensor_msgs/msg/PointCloud2` messages of one topic, read
//! one at a time through the `mcap` crate ([`BagClouds`]), and the list of a bag's topics
//! ([`topics`]). A bag is an `.mcap` file, or a rosbag2 folder holding `metadata.yaml` and
//! its `.mcap` files (read in the order `metadata.yaml` lists them).
//!
//! Memory is bounded by a message (or an MCAP chunk), not by the bag: messages are
//! streamed from the file ([`mcap::io::MessageReader`]) and each is decoded
//! ([`cdr::decode_point_cloud2`]) as it is taken. A truncated or damaged bag yields the
//! messages before the damage, then one [`BagError::Damaged`] naming the byte it was
//! found at.

pub mod cdr;

use std::collections::BTreeMap;
use std::fs::File;
use std::io::{BufReader, Read, Seek};
use std::path::{Path, PathBuf};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

pub use cdr::{
    ODOMETRY, OdometryPosition, POINT_CLOUD2, PointCloud2, decode_odometry, decode_point_cloud2,
};

use crate::read::ReadError;

/// The first bytes of an MCAP file.
pub const MCAP_MAGIC: &[u8] = b"\x89MCAP0\r\n";

/// The longest MCAP record read (1 GiB): a PointCloud2 of the largest ToF and lidar
/// clouds (a 1280×960 organised cloud of 32-byte points is 39 MB) is far below it; it
/// bounds what a damaged record's length can make the reader allocate. (Not the file's
/// size: a record inside a compressed chunk may be longer than the whole file.)
pub const MAX_RECORD_BYTES: u64 = 1 << 30;

/// The size of the read buffer between the file and the MCAP reader.
const READ_BUFFER_BYTES: usize = 1 << 20;

/// What went wrong with a bag.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[non_exhaustive]
pub enum BagError {
    /// The bag could not be opened or is not an MCAP bag (the message says why).
    #[error("{0}")]
    Open(String),
    /// The MCAP data is truncated or damaged: the messages before it were read.
    #[error(
        "{file}: {message} (at or before byte {offset} of the file); the {read} messages \
         of the topic before it were read"
    )]
    Damaged {
        /// The `.mcap` file.
        file: String,
        /// The byte of the file the reader had reached when it found the damage.
        offset: u64,
        /// The MCAP reader's message.
        message: String,
        /// Messages of the topic read before it.
        read: u64,
    },
    /// The topic asked for is not in the bag, not a PointCloud2, or must be named.
    #[error("{0}")]
    Topic(String),
}

/// One topic of a bag.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct TopicInfo {
    /// The topic's name (`/camera/points`).
    pub topic: String,
    /// Its message type (`sensor_msgs/msg/PointCloud2`).
    pub message_type: String,
    /// Its message encoding (`cdr`).
    pub encoding: String,
    /// Its number of messages.
    pub count: u64,
}

/// The topics of a bag, by name.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct Topics {
    /// Every topic, sorted by name.
    pub topics: Vec<TopicInfo>,
    /// Where the counts stop short: a file was damaged (counted up to the damage).
    pub damaged: Option<BagError>,
}

impl Topics {
    /// The topics of type `sensor_msgs/msg/PointCloud2`.
    pub fn point_clouds(&self) -> impl Iterator<Item = &TopicInfo> {
        self.topics
            .iter()
            .filter(|t| t.message_type == POINT_CLOUD2)
    }

    /// The topic to read: `topic` when given (it must be a PointCloud2 topic of the bag),
    /// else the bag's only PointCloud2 topic; an error naming the candidates otherwise.
    pub fn choose(&self, topic: Option<&str>) -> Result<String, BagError> {
        let clouds: Vec<&str> = self.point_clouds().map(|t| t.topic.as_str()).collect();
        let listed = |names: &[&str]| {
            if names.is_empty() {
                "none".to_string()
            } else {
                names.join(", ")
            }
        };
        match topic {
            Some(t) => match self.topics.iter().find(|i| i.topic == t) {
                Some(i) if i.message_type == POINT_CLOUD2 && i.encoding == "cdr" => {
                    Ok(t.to_string())
                }
                Some(i) => Err(BagError::Topic(format!(
                    "--topic {t}: its messages are {} ({}), not {POINT_CLOUD2} (cdr); the \
                     PointCloud2 topics are: {}",
                    i.message_type,
                    i.encoding,
                    listed(&clouds)
                ))),
                None => Err(BagError::Topic(format!(
                    "--topic {t}: no such topic in the bag; its PointCloud2 topics are: {}",
                    listed(&clouds)
                ))),
            },
            None => match clouds.as_slice() {
                [one] => Ok(one.to_string()),
                [] => Err(BagError::Topic(format!(
                    "the bag has no {POINT_CLOUD2} topic (its topics: {})",
                    listed(
                        &self
                            .topics
                            .iter()
                            .map(|t| t.topic.as_str())
                            .collect::<Vec<_>>()
                    )
                ))),
                many => Err(BagError::Topic(format!(
                    "the bag has {} PointCloud2 topics: {}; choose one with --topic",
                    many.len(),
                    many.join(", ")
                ))),
            },
        }
    }
}

/// Whether `path` is a bag: a folder holding `metadata.yaml`, a file named `.mcap`, or a
/// file starting with the MCAP magic bytes.
pub fn is_bag(path: &Path) -> bool {
    if path.is_dir() {
        return path.join("metadata.yaml").is_file();
    }
    if path
        .extension()
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
    {
        return true;
    }
    // Sniffed only in a regular file: opening a FIFO would wait for a writer (the
    // readers then refuse it by name).
    let mut head = [0u8; 8];
    crate::read::open_regular(path)
        .is_ok_and(|(mut f, _)| f.read_exact(&mut head).is_ok() && head == MCAP_MAGIC)
}

/// The `.mcap` files of a bag, in order: the file itself, or those a rosbag2 folder's
/// `metadata.yaml` lists (`relative_file_paths`), else the folder's `.mcap` files by name.
pub fn bag_files(path: &Path) -> Result<Vec<PathBuf>, BagError> {
    let shown = crate::name::shown(path);
    if !path.is_dir() {
        return Ok(vec![path.to_path_buf()]);
    }
    let meta = path.join("metadata.yaml");
    let text = std::fs::read_to_string(&meta)
        .map_err(|e| BagError::Open(format!("{shown}/metadata.yaml: cannot read: {e}")))?;
    let storage = yaml_value(&text, "storage_identifier");
    if let Some(s) = storage.as_deref()
        && s != "mcap"
    {
        return Err(BagError::Open(format!(
            "{shown}: a rosbag2 bag in `{s}` storage; only MCAP is read (convert it with \
             `ros2 bag convert` or rosbags-convert to MCAP storage)"
        )));
    }
    if yaml_value(&text, "compression_mode").is_some_and(|m| m.eq_ignore_ascii_case("file")) {
        return Err(BagError::Open(format!(
            "{shown}: the bag's files are compressed whole (compression_mode FILE); \
             decompress them first (`ros2 bag decompress`, or `zstd -d` on each file)"
        )));
    }
    let mut files: Vec<PathBuf> = yaml_list(&text, "relative_file_paths")
        .into_iter()
        .map(|f| path.join(f))
        .collect();
    if files.is_empty() {
        let entries = std::fs::read_dir(path)
            .map_err(|e| BagError::Open(format!("{shown}: cannot list the folder: {e}")))?;
        files = entries
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.extension().is_some_and(|e| e == "mcap"))
            .collect();
        files.sort();
    }
    if files.is_empty() {
        return Err(BagError::Open(format!(
            "{shown}: a rosbag2 folder without .mcap files"
        )));
    }
    Ok(files)
}

/// The scalar value of `key:` in a YAML text (the first such line, quotes removed).
fn yaml_value(text: &str, key: &str) -> Option<String> {
    text.lines().find_map(|l| {
        let rest = l.trim_start().strip_prefix(key)?.strip_prefix(':')?;
        let v = rest.trim().trim_matches(|c| c == '"' || c == '\'');
        (!v.is_empty()).then(|| v.to_string())
    })
}

/// The items of the block list under `key:` in a YAML text (`- item` lines).
fn yaml_list(text: &str, key: &str) -> Vec<String> {
    let mut lines = text.lines().skip_while(|l| {
        l.trim_start()
            .strip_prefix(key)
            .is_none_or(|r| !r.starts_with(':'))
    });
    if lines.next().is_none() {
        return Vec::new();
    }
    lines
        .map(str::trim)
        .take_while(|l| l.starts_with('-'))
        .map(|l| {
            l.trim_start_matches('-')
                .trim()
                .trim_matches(|c| c == '"' || c == '\'')
                .to_string()
        })
        .filter(|f| !f.is_empty())
        .collect()
}

/// A reader that counts the bytes it hands on: the position the MCAP reader has reached.
struct Counting<R> {
    inner: R,
    count: Arc<AtomicU64>,
}

impl<R: Read> Read for Counting<R> {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        self.count.fetch_add(n as u64, Ordering::Relaxed);
        Ok(n)
    }
}

type Messages = mcap::io::MessageReader<Counting<BufReader<File>>>;

/// Open one `.mcap` file for streaming; the counter follows the reader's position.
fn open_messages(file: &Path) -> Result<(Messages, Arc<AtomicU64>), BagError> {
    let shown = crate::name::shown(file);
    let (f, _len) =
        crate::read::open_regular(file).map_err(|e| BagError::Open(format!("{shown}: {e}")))?;
    let count = Arc::new(AtomicU64::new(0));
    let source = Counting {
        inner: BufReader::with_capacity(READ_BUFFER_BYTES, f),
        count: Arc::clone(&count),
    };
    let limit = usize::try_from(MAX_RECORD_BYTES).unwrap_or(usize::MAX);
    // The chunks' CRCs are checked before any of their messages is given out, and the data
    // section's at its end: a flipped bit in a recorded cloud is damage, not a wrong pose.
    let options = mcap::sans_io::LinearReaderOptions::default()
        .with_record_length_limit(limit)
        .with_prevalidate_chunk_crcs(true)
        .with_validate_data_section_crc(true);
    Ok((
        mcap::io::MessageReader::new_with_options(source, options),
        count,
    ))
}

/// The error for the MCAP reader's `e` in `file` at `offset`.
fn damaged(file: &Path, offset: u64, e: &mcap::McapError, read: u64) -> BagError {
    let message = match e {
        mcap::McapError::UnexpectedEof => {
            "the file ends in the middle of a record (truncated: a recording cut short?)".into()
        }
        mcap::McapError::BadMagic => {
            "not an MCAP file (its first bytes are not the MCAP magic)".into()
        }
        other => format!("damaged MCAP data: {other}"),
    };
    BagError::Damaged {
        file: crate::name::shown(file),
        offset,
        message,
        read,
    }
}

/// The topics of a bag with their types and message counts: from each file's summary
/// section when it has one, else by reading its messages (a damaged file is counted up to
/// the damage, which [`Topics::damaged`] names).
pub fn topics(path: &Path) -> Result<Topics, BagError> {
    let mut by_name: BTreeMap<String, TopicInfo> = BTreeMap::new();
    let mut damaged_at = None;
    for file in bag_files(path)? {
        let mut add = |topic: &str, ty: &str, enc: &str, n: u64| {
            by_name
                .entry(topic.to_string())
                .or_insert_with(|| TopicInfo {
                    topic: topic.to_string(),
                    message_type: ty.to_string(),
                    encoding: enc.to_string(),
                    count: 0,
                })
                .count += n;
        };
        let schema_name =
            |c: &mcap::Channel<'_>| c.schema.as_ref().map_or(String::new(), |s| s.name.clone());
        if let Some(summary) = read_summary(&file)
            && let Some(stats) = &summary.stats
        {
            for (id, c) in &summary.channels {
                let n = stats.channel_message_counts.get(id).copied().unwrap_or(0);
                add(&c.topic, &schema_name(c), &c.message_encoding, n);
            }
            continue;
        }
        let (messages, count) = open_messages(&file)?;
        for m in messages {
            match m {
                Ok(m) => add(
                    &m.channel.topic,
                    &schema_name(&m.channel),
                    &m.channel.message_encoding,
                    1,
                ),
                Err(e) => {
                    let n = by_name.values().map(|t| t.count).sum();
                    damaged_at = Some(damaged(&file, count.load(Ordering::Relaxed), &e, n));
                    break;
                }
            }
        }
        if damaged_at.is_some() {
            break;
        }
    }
    Ok(Topics {
        topics: by_name.into_values().collect(),
        damaged: damaged_at,
    })
}

/// The summary section of an MCAP file, when it has one that can be read.
fn read_summary(file: &Path) -> Option<mcap::Summary> {
    let (mut f, len) = crate::read::open_regular(file).ok()?;
    let options = mcap::sans_io::SummaryReaderOptions::default()
        .with_file_size(len)
        .with_record_length_limit(usize::try_from(len.min(MAX_RECORD_BYTES)).ok()?);
    let mut reader = mcap::sans_io::SummaryReader::new_with_options(options);
    while let Some(event) = reader.next_event() {
        match event.ok()? {
            mcap::sans_io::SummaryReadEvent::ReadRequest(need) => {
                let n = f.read(reader.insert(need)).ok()?;
                reader.notify_read(n);
            }
            mcap::sans_io::SummaryReadEvent::SeekRequest(to) => {
                reader.notify_seeked(f.seek(to).ok()?);
            }
        }
    }
    reader.finish()
}

/// One message of the topic.
#[derive(Clone, Debug, PartialEq)]
pub struct BagMessage {
    /// Its index among the topic's messages (0 first).
    pub index: u64,
    /// Its MCAP log time (ns).
    pub log_time_ns: u64,
    /// The decoded cloud, or why this message could not be decoded (the next ones are
    /// still read).
    pub cloud: Result<PointCloud2, ReadError>,
}

/// The messages of one topic of a bag, in file order, as raw bytes; those outside a range
/// of indices are counted, not copied. After a [`BagError`] the iterator ends.
struct TopicMessages {
    files: std::vec::IntoIter<PathBuf>,
    current: Option<(PathBuf, Messages, Arc<AtomicU64>)>,
    topic: String,
    index: u64,
    keep: std::ops::Range<u64>,
    done: bool,
}

impl TopicMessages {
    fn open(path: &Path, topic: &str) -> Result<TopicMessages, BagError> {
        Ok(TopicMessages {
            files: bag_files(path)?.into_iter(),
            current: None,
            topic: topic.to_string(),
            index: 0,
            keep: 0..u64::MAX,
            done: false,
        })
    }
}

impl Iterator for TopicMessages {
    /// (index among the topic's messages, MCAP log time in ns, the message's bytes).
    type Item = Result<(u64, u64, Vec<u8>), BagError>;

    fn next(&mut self) -> Option<Self::Item> {
        while !self.done {
            if self.index >= self.keep.end {
                // Past the range kept: the rest of the bag is not read.
                self.done = true;
                return None;
            }
            if self.current.is_none() {
                let file = self.files.next()?;
                match open_messages(&file) {
                    Ok((m, c)) => self.current = Some((file, m, c)),
                    Err(e) => {
                        self.done = true;
                        return Some(Err(e));
                    }
                }
            }
            let (file, messages, count) = self.current.as_mut()?;
            match messages.next() {
                None => self.current = None,
                Some(Err(e)) => {
                    self.done = true;
                    let read = self.index.saturating_sub(self.keep.start);
                    return Some(Err(damaged(file, count.load(Ordering::Relaxed), &e, read)));
                }
                Some(Ok(m)) if m.channel.topic != self.topic => {}
                Some(Ok(m)) => {
                    let index = self.index;
                    self.index += 1;
                    if !self.keep.contains(&index) {
                        continue;
                    }
                    return Some(Ok((index, m.log_time, m.data.into_owned())));
                }
            }
        }
        None
    }
}

/// The PointCloud2 messages of one topic of a bag, in file order, decoded one at a time.
/// After a [`BagError`] the iterator ends.
pub struct BagClouds {
    messages: TopicMessages,
}

impl BagClouds {
    /// Open `path` (an `.mcap` file or a rosbag2 folder) for the messages of `topic`, which
    /// the caller chose ([`Topics::choose`]); other topics are skipped.
    pub fn open(path: &Path, topic: &str) -> Result<BagClouds, BagError> {
        Ok(BagClouds {
            messages: TopicMessages::open(path, topic)?,
        })
    }

    /// Only the messages whose index (among the topic's, from 0) lies in `keep`: the others
    /// are skipped undecoded, and the bag is not read past `keep.end` (a `--shard`'s block).
    pub fn only(mut self, keep: std::ops::Range<u64>) -> BagClouds {
        self.messages.keep = keep;
        self
    }

    /// The topic read.
    pub fn topic(&self) -> &str {
        &self.messages.topic
    }
}

impl Iterator for BagClouds {
    type Item = Result<BagMessage, BagError>;

    fn next(&mut self) -> Option<Self::Item> {
        Some(
            self.messages
                .next()?
                .map(|(index, log_time_ns, data)| BagMessage {
                    index,
                    log_time_ns,
                    cloud: decode_point_cloud2(&data),
                }),
        )
    }
}

/// The positions of an odometry topic, with what stopped the reading early.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct OdometryTrack {
    /// Every message's stamp and position, in bag order.
    pub positions: Vec<OdometryPosition>,
    /// Messages that could not be decoded: (index, why).
    pub undecoded: Vec<(u64, String)>,
    /// The damage that ended the reading (the positions before it are kept).
    pub damaged: Option<BagError>,
}

/// Every position of the `nav_msgs/msg/Odometry` topic `topic` of a bag. An odometry
/// message is a few hundred bytes: a run of hours at 100 Hz holds a few ten thousand
/// positions (24 bytes each) in memory; the clouds are never read.
pub fn odometry(path: &Path, topic: &str) -> Result<OdometryTrack, BagError> {
    let found = topics(path)?;
    let Some(info) = found.topics.iter().find(|t| t.topic == topic) else {
        let names: Vec<&str> = found.topics.iter().map(|t| t.topic.as_str()).collect();
        return Err(BagError::Topic(format!(
            "{}: no topic `{topic}` (the bag has: {})",
            crate::name::shown(path),
            names.join(", ")
        )));
    };
    if info.message_type != ODOMETRY {
        return Err(BagError::Topic(format!(
            "{}: topic `{topic}` holds {} messages, not {ODOMETRY}",
            crate::name::shown(path),
            info.message_type
        )));
    }
    let mut track = OdometryTrack::default();
    for m in TopicMessages::open(path, topic)? {
        match m {
            Ok((index, _, data)) => match decode_odometry(&data) {
                Ok(p) => track.positions.push(p),
                Err(e) => track.undecoded.push((index, e.to_string())),
            },
            Err(e) => {
                track.damaged = Some(e);
                break;
            }
        }
    }
    Ok(track)
}

#[cfg(test)]
mod tests {
    use super::cdr::tests::{F, message};
    use super::*;
    use std::collections::BTreeMap;

    /// A PointCloud2 message of `n` float32 points, the i-th at (k + i, 0.5, -0.5).
    fn cloud(k: u32, n: u32) -> Vec<u8> {
        let fields: Vec<F> = vec![("x", 0, 7, 1), ("y", 4, 7, 1), ("z", 8, 7, 1)];
        let data: Vec<u8> = (0..n)
            .flat_map(|i| [(k + i) as f32, 0.5, -0.5])
            .flat_map(f32::to_le_bytes)
            .collect();
        message(true, "cam", (1, n), &fields, false, 12, 12 * n, &data)
    }

    /// An MCAP file (mcap's own writer, chunked or not) of 6 clouds on `/points`
    /// interleaved with 6 messages on `/other`; its bytes.
    fn bag(chunked: bool) -> Vec<u8> {
        bag_compressed(chunked, None)
    }

    /// [`bag`] with its chunks compressed.
    fn bag_compressed(chunked: bool, compression: Option<mcap::Compression>) -> Vec<u8> {
        let mut out = std::io::Cursor::new(Vec::new());
        {
            let opts = mcap::WriteOptions::new()
                .use_chunks(chunked)
                .compression(compression)
                .chunk_size(Some(4096));
            let mut w = opts.create(&mut out).unwrap();
            let s = w.add_schema(POINT_CLOUD2, "ros2msg", b"").unwrap();
            let t = w.add_schema("std_msgs/msg/String", "ros2msg", b"").unwrap();
            let points = w
                .add_channel(s, "/points", "cdr", &BTreeMap::new())
                .unwrap();
            let other = w.add_channel(t, "/other", "cdr", &BTreeMap::new()).unwrap();
            for k in 0..6u32 {
                for (ch, data) in [
                    (other, vec![0, 1, 0, 0, 1, 0, 0, 0, 0]),
                    (points, cloud(k, 200)),
                ] {
                    let h = mcap::records::MessageHeader {
                        channel_id: ch,
                        sequence: k,
                        log_time: u64::from(k),
                        publish_time: u64::from(k),
                    };
                    w.write_to_known_channel(&h, &data).unwrap();
                }
            }
            w.finish().unwrap();
        }
        out.into_inner()
    }

    fn write(dir: &Path, name: &str, bytes: &[u8]) -> PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }

    /// The topic's messages in order, the other topic skipped; the topics listed with their
    /// counts (from the summary, and counted when there is none).
    #[test]
    fn messages_of_one_topic_in_order() {
        let dir = tempfile::tempdir().unwrap();
        for chunked in [false, true] {
            let p = write(dir.path(), "a.mcap", &bag(chunked));
            assert!(is_bag(&p));
            let t = topics(&p).unwrap();
            assert_eq!(t.damaged, None);
            let names: Vec<(&str, u64)> = t
                .topics
                .iter()
                .map(|i| (i.topic.as_str(), i.count))
                .collect();
            assert_eq!(names, [("/other", 6), ("/points", 6)]);
            assert_eq!(t.choose(None).unwrap(), "/points");
            assert!(
                t.choose(Some("/other"))
                    .unwrap_err()
                    .to_string()
                    .contains("std_msgs/msg/String")
            );
            assert!(
                t.choose(Some("/nope"))
                    .unwrap_err()
                    .to_string()
                    .contains("no such topic")
            );
            let got: Vec<BagMessage> = BagClouds::open(&p, "/points")
                .unwrap()
                .map(Result::unwrap)
                .collect();
            assert_eq!(got.len(), 6);
            for (k, m) in got.iter().enumerate() {
                assert_eq!(m.index, k as u64);
                let c = m.cloud.as_ref().unwrap();
                assert_eq!(c.cloud.points[0], [k as f64, 0.5, -0.5]);
                assert_eq!(c.stamp_ns, -3_000_000_000 + 250_000_000);
            }
        }
    }

    /// `only(2..4)` yields messages 2 and 3 with their indices; the others are not decoded,
    /// and an empty range yields nothing.
    #[test]
    fn only_a_range_of_messages() {
        let dir = tempfile::tempdir().unwrap();
        let p = write(dir.path(), "a.mcap", &bag(true));
        let got: Vec<u64> = BagClouds::open(&p, "/points")
            .unwrap()
            .only(2..4)
            .map(|m| m.unwrap().index)
            .collect();
        assert_eq!(got, [2, 3]);
        let first = BagClouds::open(&p, "/points").unwrap().only(5..9).next();
        let c = first.unwrap().unwrap().cloud.unwrap();
        assert_eq!(c.cloud.points[0], [5.0, 0.5, -0.5]);
        assert_eq!(
            BagClouds::open(&p, "/points").unwrap().only(3..3).count(),
            0
        );
        // Not an odometry topic: refused with its type.
        let e = odometry(&p, "/points").unwrap_err().to_string();
        assert!(e.contains(ODOMETRY) && e.contains(POINT_CLOUD2), "{e}");
    }

    /// Chunks compressed with zstd or lz4 (as `ros2 bag record` may write them), whose
    /// records can be longer than the whole file: every cloud read.
    #[test]
    fn compressed_chunks() {
        let dir = tempfile::tempdir().unwrap();
        for c in [mcap::Compression::Zstd, mcap::Compression::Lz4] {
            let p = write(dir.path(), "z.mcap", &bag_compressed(true, Some(c)));
            let n = BagClouds::open(&p, "/points")
                .unwrap()
                .map(|m| m.unwrap().cloud.unwrap().cloud.points.len())
                .collect::<Vec<_>>();
            assert_eq!(n, [200; 6], "{c:?}");
        }
    }

    /// A file cut anywhere after the first cloud: the clouds before the cut, then one error
    /// naming the byte reached, never a panic; the topics counted up to the damage.
    #[test]
    fn truncated_bags_keep_what_was_read() {
        let dir = tempfile::tempdir().unwrap();
        for chunked in [false, true] {
            let whole = bag(chunked);
            let mut last_n = 0;
            for cut in (40..whole.len() - 1).step_by(97) {
                let p = write(dir.path(), "cut.mcap", &whole[..cut]);
                let items: Vec<_> = BagClouds::open(&p, "/points").unwrap().collect();
                let (ok, err): (Vec<_>, Vec<_>) = items.into_iter().partition(Result::is_ok);
                // Messages come in order and never fewer as the cut moves on.
                assert!(ok.len() >= last_n, "cut {cut}");
                last_n = ok.len();
                for (k, m) in ok.iter().enumerate() {
                    assert_eq!(m.as_ref().unwrap().index, k as u64);
                }
                let [
                    Err(BagError::Damaged {
                        offset,
                        read,
                        message,
                        ..
                    }),
                ] = err.as_slice()
                else {
                    panic!("cut {cut}: {err:?}");
                };
                assert_eq!(*read, ok.len() as u64);
                assert!(*offset <= cut as u64, "{offset} > {cut}");
                assert!(
                    message.contains("truncated") || message.contains("damaged"),
                    "{message}"
                );
                let t = topics(&p).unwrap();
                assert!(t.damaged.is_some(), "cut {cut}");
            }
            assert_eq!(
                last_n, 6,
                "chunked {chunked}: every cloud before the summary read"
            );
        }
    }

    /// One bit flipped in a cloud's coordinates is damage the CRCs catch: a chunked bag's
    /// chunk fails before any of its messages is given out, an unchunked bag's data
    /// section at its end (a flipped bit had changed a point and gone unnoticed).
    #[test]
    fn a_flipped_bit_fails_the_crc() {
        let dir = tempfile::tempdir().unwrap();
        for chunked in [true, false] {
            let mut b = bag(chunked);
            // The y coordinate 0.5f32 of the first cloud's first point.
            let half = 0.5f32.to_le_bytes();
            let at = b.windows(4).position(|w| w == half).unwrap();
            b[at] ^= 1;
            let p = write(dir.path(), "flip.mcap", &b);
            let items: Vec<_> = BagClouds::open(&p, "/points").unwrap().collect();
            let damage = items
                .iter()
                .find_map(|m| m.as_ref().err())
                .map(|e| e.to_string());
            let damage = damage.unwrap_or_else(|| panic!("chunked {chunked}: no damage seen"));
            assert!(damage.contains("CRC"), "chunked {chunked}: {damage}");
            if chunked {
                assert!(items[0].is_err(), "the chunk's messages were given out");
            }
        }
    }

    /// A rosbag2 folder: the files `metadata.yaml` lists, in its order; another storage or
    /// whole-file compression refused with what to do.
    #[test]
    fn rosbag2_folders() {
        let dir = tempfile::tempdir().unwrap();
        let d = dir.path();
        write(d, "run_1.mcap", &bag(true));
        write(d, "run_0.mcap", &bag(false));
        let yaml = "rosbag2_bagfile_information:\n  version: 9\n  storage_identifier: mcap\n  \
                    relative_file_paths:\n  - run_1.mcap\n  - 'run_0.mcap'\n  starting_time:\n";
        write(d, "metadata.yaml", yaml.as_bytes());
        assert!(is_bag(d));
        assert_eq!(
            bag_files(d).unwrap(),
            [d.join("run_1.mcap"), d.join("run_0.mcap")]
        );
        assert_eq!(BagClouds::open(d, "/points").unwrap().count(), 12);
        assert_eq!(topics(d).unwrap().topics[1].count, 12);
        write(d, "metadata.yaml", b"x:\n  storage_identifier: sqlite3\n");
        assert!(
            bag_files(d)
                .unwrap_err()
                .to_string()
                .contains("only MCAP is read")
        );
        write(
            d,
            "metadata.yaml",
            b"x:\n  storage_identifier: mcap\n  compression_mode: FILE\n",
        );
        assert!(bag_files(d).unwrap_err().to_string().contains("decompress"));
        // Not an MCAP file at all.
        let p = write(d, "junk.mcap", b"ply\nformat ascii 1.0\n");
        let e = BagClouds::open(&p, "/points")
            .unwrap()
            .next()
            .unwrap()
            .unwrap_err();
        assert!(e.to_string().contains("not an MCAP file"), "{e}");
    }
}
