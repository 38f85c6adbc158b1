//! Reading softcap (and any other) MCAP files, with errors that name the file.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use sha2::{Digest, Sha256};

use crate::catalog::{SoftcapMessage, Topic};
use crate::error::{Error, Result};
use crate::provenance::{INPUTS_KEY, InputFile, PROVENANCE_METADATA, Provenance, TIMESTAMP_KEY};

/// Largest uncompressed size one chunk may declare (softcap's writer makes chunks of about a
/// MiB; a single large message gets its own). A larger claim is refused before anything is
/// allocated or decompressed: a decompression bomb is bad input (exit code 2).
pub const MAX_CHUNK_BYTES: u64 = 256 << 20;

/// Largest total uncompressed size of all chunks of one file.
pub const MAX_UNCOMPRESSED_BYTES: u64 = 2 << 30;

/// One channel of a recording, as listed in its summary.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelSummary {
    /// MCAP channel id.
    pub id: u16,
    /// Topic name.
    pub topic: String,
    /// Schema name (`softcap.MarkerFrame`, `foxglove.SceneUpdate`), empty if schemaless.
    pub schema_name: String,
    /// Schema encoding (`protobuf`, `jsonschema`, ...).
    pub schema_encoding: String,
    /// Message encoding (`protobuf`, `json`, ...).
    pub message_encoding: String,
    /// Number of messages (from the summary statistics).
    pub message_count: u64,
}

/// A message read from a recording, with its channel's description.
#[derive(Debug, Clone, PartialEq)]
pub struct RawMessage {
    /// Topic name.
    pub topic: String,
    /// Schema name, empty if schemaless.
    pub schema_name: String,
    /// Message encoding.
    pub message_encoding: String,
    /// Log time, ns since session start.
    pub log_time_ns: u64,
    /// Encoded message bytes.
    pub data: Vec<u8>,
}

/// An MCAP file read into memory and validated.
///
/// [`Recording::open`] checks the magic bytes, the footer and summary section and reads every
/// record once (chunk CRCs included), so a corrupt or truncated file is reported up front as
/// [`Error::Corrupt`] or [`Error::Truncated`] naming the file and the problem.
#[derive(Debug)]
pub struct Recording {
    path: PathBuf,
    bytes: Vec<u8>,
    summary: mcap::Summary,
}

impl Recording {
    /// Reads and validates `path`.
    pub fn open(path: impl AsRef<Path>) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        let bytes = std::fs::read(&path).map_err(|source| Error::Io {
            path: path.clone(),
            action: "reading",
            source,
        })?;
        Self::from_bytes(path, bytes)
    }

    /// Validates an in-memory MCAP file; `path` is used in error messages.
    pub fn from_bytes(path: impl Into<PathBuf>, bytes: Vec<u8>) -> Result<Self> {
        let path = path.into();
        let len = bytes.len() as u64;
        let magic = mcap::MAGIC;
        if bytes.len() < magic.len() || &bytes[..magic.len()] != magic {
            let problem = if bytes.is_empty() {
                "file is empty".to_string()
            } else {
                "does not start with the MCAP magic bytes (not an MCAP file)".to_string()
            };
            return Err(Error::Corrupt { path, problem });
        }
        if bytes.len() < 2 * magic.len() || &bytes[bytes.len() - magic.len()..] != magic {
            return Err(Error::Truncated {
                path,
                len,
                problem: "no end magic: the file ends before its footer (writer did not finish)"
                    .into(),
            });
        }
        check_chunk_sizes(&path, &bytes)?;
        check_record_lengths(&path, &bytes)?;
        let summary = match mcap::Summary::read(&bytes) {
            Ok(Some(s)) => s,
            Ok(None) => {
                return Err(Error::Corrupt {
                    path,
                    problem: "no summary section (softcap files always have one)".into(),
                });
            }
            Err(e) => return Err(classify(path, len, &e)),
        };
        let recording = Self {
            path,
            bytes,
            summary,
        };
        // One full pass: every record parses, every chunk decompresses and matches its CRC.
        for message in recording.raw_stream()? {
            message.map_err(|e| classify(recording.path.clone(), len, &e))?;
        }
        Ok(recording)
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The whole file's bytes.
    pub fn bytes(&self) -> &[u8] {
        &self.bytes
    }

    /// The parsed summary section (`mcap` crate type).
    pub fn summary(&self) -> &mcap::Summary {
        &self.summary
    }

    /// Message count and log-time range `(start, end)` in ns, from the summary statistics.
    pub fn stats(&self) -> (u64, Option<(u64, u64)>) {
        match &self.summary.stats {
            Some(s) if s.message_count > 0 => (
                s.message_count,
                Some((s.message_start_time, s.message_end_time)),
            ),
            Some(s) => (s.message_count, None),
            None => (0, None),
        }
    }

    /// Every channel, ordered by topic.
    pub fn channels(&self) -> Vec<ChannelSummary> {
        let counts = self
            .summary
            .stats
            .as_ref()
            .map(|s| s.channel_message_counts.clone())
            .unwrap_or_default();
        let mut out: Vec<ChannelSummary> = self
            .summary
            .channels
            .values()
            .map(|c| ChannelSummary {
                id: c.id,
                topic: c.topic.clone(),
                schema_name: c
                    .schema
                    .as_ref()
                    .map(|s| s.name.clone())
                    .unwrap_or_default(),
                schema_encoding: c
                    .schema
                    .as_ref()
                    .map(|s| s.encoding.clone())
                    .unwrap_or_default(),
                message_encoding: c.message_encoding.clone(),
                message_count: counts.get(&c.id).copied().unwrap_or(0),
            })
            .collect();
        out.sort_by(|a, b| a.topic.cmp(&b.topic).then(a.id.cmp(&b.id)));
        out
    }

    /// The channel of `topic`, if present.
    pub fn channel(&self, topic: &str) -> Option<ChannelSummary> {
        self.channels().into_iter().find(|c| c.topic == topic)
    }

    /// The schema record (name, encoding, data) of `topic`'s channel.
    pub fn schema_of(&self, topic: &str) -> Option<(String, String, Vec<u8>)> {
        self.summary
            .channels
            .values()
            .find(|c| c.topic == topic)
            .and_then(|c| c.schema.as_ref())
            .map(|s| (s.name.clone(), s.encoding.clone(), s.data.to_vec()))
    }

    fn raw_stream(&self) -> Result<mcap::MessageStream<'_>> {
        mcap::MessageStream::new(&self.bytes)
            .map_err(|e| classify(self.path.clone(), self.bytes.len() as u64, &e))
    }

    /// Every message in file order.
    pub fn messages(&self) -> Result<Vec<RawMessage>> {
        let len = self.bytes.len() as u64;
        self.raw_stream()?
            .map(|m| {
                let m = m.map_err(|e| classify(self.path.clone(), len, &e))?;
                Ok(RawMessage {
                    topic: m.channel.topic.clone(),
                    schema_name: m
                        .channel
                        .schema
                        .as_ref()
                        .map(|s| s.name.clone())
                        .unwrap_or_default(),
                    message_encoding: m.channel.message_encoding.clone(),
                    log_time_ns: m.log_time,
                    data: m.data.into_owned(),
                })
            })
            .collect()
    }

    /// Every message on `topic`, in file order.
    pub fn messages_on(&self, topic: &str) -> Result<Vec<RawMessage>> {
        Ok(self
            .messages()?
            .into_iter()
            .filter(|m| m.topic == topic)
            .collect())
    }

    /// Decodes every message on `topic` as `M`: `(log_time_ns, message)` in file order.
    ///
    /// Errors if the channel is missing, carries another schema, or a message does not decode.
    pub fn read<M: SoftcapMessage>(&self, topic: &Topic<M>) -> Result<Vec<(u64, M)>> {
        let name = topic.name();
        let channel = self.channel(name).ok_or_else(|| Error::MissingChannel {
            path: self.path.clone(),
            topic: name.into(),
        })?;
        let expected = M::schema_name();
        if channel.schema_name != expected || channel.message_encoding != "protobuf" {
            return Err(Error::WrongSchema {
                path: self.path.clone(),
                topic: name.into(),
                expected,
                found: channel.schema_name,
                encoding: channel.message_encoding,
            });
        }
        self.messages_on(name)?
            .into_iter()
            .map(|m| {
                M::decode(m.data.as_slice())
                    .map(|msg| (m.log_time_ns, msg))
                    .map_err(|source| Error::Decode {
                        path: self.path.clone(),
                        topic: name.into(),
                        log_time_ns: m.log_time_ns,
                        source,
                    })
            })
            .collect()
    }

    /// Decodes the single (static) message on `topic`.
    pub fn read_static<M: SoftcapMessage>(&self, topic: &Topic<M>) -> Result<M> {
        let mut all = self.read(topic)?;
        if all.len() != 1 {
            return Err(Error::NotStatic {
                path: self.path.clone(),
                topic: topic.name().into(),
                count: all.len(),
            });
        }
        Ok(all.remove(0).1)
    }

    /// Every metadata record `(name, key → value)`, in file order.
    pub fn metadata(&self) -> Result<Vec<(String, BTreeMap<String, String>)>> {
        let len = self.bytes.len() as u64;
        self.summary
            .metadata_indexes
            .iter()
            .map(|idx| {
                mcap::read::metadata(&self.bytes, idx)
                    .map(|m| (m.name, m.metadata))
                    .map_err(|e| classify(self.path.clone(), len, &e))
            })
            .collect()
    }

    /// The `softcap.provenance` record, if the file has one.
    pub fn provenance(&self) -> Result<Option<Provenance>> {
        self.metadata()?
            .into_iter()
            .find(|(name, _)| name == PROVENANCE_METADATA)
            .map(|(_, m)| Provenance::from_metadata(&self.path, &m))
            .transpose()
    }

    /// Content digest (lower-case hex SHA-256); equal for files with equal content.
    ///
    /// Hashes, each field length-prefixed: every channel ordered by topic (topic, message
    /// encoding, schema name, encoding and data, channel metadata); every message in file order
    /// (topic, log time, data); every metadata record in file order (name, then its sorted
    /// key/values, leaving out the `timestamp` of `softcap.provenance` and hashing each MCAP input
    /// by its own content digest instead of its bytes); every attachment (name,
    /// media type, data). Chunking, compression, record offsets and the writer library do not
    /// enter, so two runs with the same inputs and arguments give the same digest.
    pub fn digest(&self) -> Result<String> {
        let mut h = Sha256::new();
        let mut put = |tag: &[u8], bytes: &[u8]| {
            h.update(tag);
            h.update((bytes.len() as u64).to_le_bytes());
            h.update(bytes);
        };
        let mut channels: Vec<_> = self.summary.channels.values().collect();
        channels.sort_by(|a, b| a.topic.cmp(&b.topic).then(a.id.cmp(&b.id)));
        for c in channels {
            put(b"C", c.topic.as_bytes());
            put(b"e", c.message_encoding.as_bytes());
            match &c.schema {
                Some(s) => {
                    put(b"S", s.name.as_bytes());
                    put(b"s", s.encoding.as_bytes());
                    put(b"d", &s.data);
                }
                None => put(b"S", b""),
            }
            for (k, v) in &c.metadata {
                put(b"k", k.as_bytes());
                put(b"v", v.as_bytes());
            }
        }
        let len = self.bytes.len() as u64;
        for m in self.raw_stream()? {
            let m = m.map_err(|e| classify(self.path.clone(), len, &e))?;
            put(b"M", m.channel.topic.as_bytes());
            put(b"t", &m.log_time.to_le_bytes());
            put(b"m", &m.data);
        }
        for (name, map) in self.metadata()? {
            put(b"D", name.as_bytes());
            for (k, v) in &map {
                if name == PROVENANCE_METADATA && k == TIMESTAMP_KEY {
                    continue;
                }
                if name == PROVENANCE_METADATA
                    && k == INPUTS_KEY
                    && let Ok(inputs) = serde_json::from_str::<Vec<InputFile>>(v)
                {
                    // An MCAP input enters by its content digest (its own timestamp left out).
                    put(b"k", k.as_bytes());
                    for i in &inputs {
                        put(b"p", i.path.as_bytes());
                        put(
                            b"h",
                            i.content_digest.as_ref().unwrap_or(&i.sha256).as_bytes(),
                        );
                    }
                    continue;
                }
                put(b"k", k.as_bytes());
                put(b"v", v.as_bytes());
            }
        }
        for idx in &self.summary.attachment_indexes {
            let a = mcap::read::attachment(&self.bytes, idx)
                .map_err(|e| classify(self.path.clone(), len, &e))?;
            put(b"A", a.name.as_bytes());
            put(b"y", a.media_type.as_bytes());
            put(b"a", &a.data);
        }
        Ok(hex::encode(h.finalize()))
    }
}

/// Walks the top-level records and refuses a chunk whose declared uncompressed size exceeds
/// [`MAX_CHUNK_BYTES`], or chunks that add up to more than [`MAX_UNCOMPRESSED_BYTES`]. Record
/// framing errors are left to the `mcap` reader, which reports them.
fn check_chunk_sizes(path: &Path, bytes: &[u8]) -> Result<()> {
    const CHUNK: u8 = 0x06;
    const FOOTER: u8 = 0x02;
    let u64_at = |at: usize| -> Option<u64> {
        Some(u64::from_le_bytes(bytes.get(at..at + 8)?.try_into().ok()?))
    };
    let mut pos = mcap::MAGIC.len();
    let mut total = 0u64;
    while let (Some(&opcode), Some(len)) = (bytes.get(pos), u64_at(pos + 1)) {
        let body = pos + 9;
        if opcode == FOOTER {
            break;
        }
        if opcode == CHUNK
            && let Err(problem) = uncompressed_chunk_records(bytes, body, len)
        {
            return Err(Error::Corrupt {
                path: path.to_path_buf(),
                problem: format!("the chunk at byte {pos}: {problem}"),
            });
        }
        if opcode == CHUNK
            && let Some(size) = u64_at(body + 16)
        {
            total = total.saturating_add(size);
            if size > MAX_CHUNK_BYTES || total > MAX_UNCOMPRESSED_BYTES {
                return Err(Error::Corrupt {
                    path: path.to_path_buf(),
                    problem: format!(
                        "the chunk at byte {pos} declares {size} uncompressed bytes ({total} so \
                         far; limits {MAX_CHUNK_BYTES} per chunk, {MAX_UNCOMPRESSED_BYTES} per \
                         file): refusing a possible decompression bomb"
                    ),
                });
            }
        }
        match usize::try_from(len).ok().and_then(|l| body.checked_add(l)) {
            Some(next) if next <= bytes.len() => pos = next,
            _ => break,
        }
    }
    Ok(())
}

/// The records of an uncompressed chunk (`body` is the chunk record's first byte after opcode and
/// length, `len` its length) must lie inside its records section, and the section inside the
/// chunk: `mcap` 0.26's linear reader subtracts each inner record's length from what is left of
/// the chunk unchecked, so a record running past the chunk's end panicked with an overflow (found
/// by the `mcap_recording` fuzz target). A chunk whose header does not fit is left to the `mcap`
/// reader, which reports it; compressed chunks are checked by `mcap` after decompression.
fn uncompressed_chunk_records(
    bytes: &[u8],
    body: usize,
    len: u64,
) -> std::result::Result<(), String> {
    let u64_at = |at: usize| -> Option<u64> {
        Some(u64::from_le_bytes(
            bytes.get(at..at.checked_add(8)?)?.try_into().ok()?,
        ))
    };
    let u32_at = |at: usize| -> Option<u32> {
        Some(u32::from_le_bytes(
            bytes.get(at..at.checked_add(4)?)?.try_into().ok()?,
        ))
    };
    // start time, end time, uncompressed size (8 bytes each), CRC (4), compression string
    let Some(compression_len) = u32_at(body + 28) else {
        return Ok(());
    };
    if compression_len != 0 {
        return Ok(());
    }
    let Some(records_len) = u64_at(body + 32) else {
        return Ok(());
    };
    let start = body + 40;
    let chunk_end = (body as u64).saturating_add(len);
    let end = (start as u64).saturating_add(records_len);
    if end > chunk_end || end > bytes.len() as u64 {
        return Err(format!(
            "its records section of {records_len} bytes runs past the end of the chunk"
        ));
    }
    let (mut at, end) = (start as u64, end);
    while at < end {
        let record_len = match u64_at(at as usize + 1) {
            Some(l) if end - at >= 9 => l,
            _ => {
                return Err(format!(
                    "a record header at byte {at} is cut by the chunk's end"
                ));
            }
        };
        if record_len > end - at - 9 {
            return Err(format!(
                "the record at byte {at} declares {record_len} bytes, {} are left in the chunk",
                end - at - 9
            ));
        }
        at += 9 + record_len;
    }
    Ok(())
}

/// One pass over every record, the records inside chunks included, with each record's length
/// limited to [`MAX_CHUNK_BYTES`] before anything is allocated for it. `mcap` 0.26's message stream
/// (`ChunkFlattener`) sets no such limit, so a corrupt length inside a chunk made it reserve an
/// impossible buffer and panic (found by the `mcap_recording` fuzz target). Then the same pass
/// from where the footer says the summary section starts, as `mcap::Summary::read` reads it: that
/// offset need not fall on a record of the first pass.
fn check_record_lengths(path: &Path, bytes: &[u8]) -> Result<()> {
    check_records_from(path, bytes, 0)?;
    // footer record (opcode, u64 length, summary_start u64, summary_offset_start u64, crc u32)
    // and the end magic: 37 bytes at the end of the file
    let footer = bytes.len().saturating_sub(37);
    let summary_start = bytes
        .get(footer + 9..footer + 17)
        .and_then(|b| b.try_into().ok())
        .map_or(0, u64::from_le_bytes);
    if summary_start > 0 && summary_start < bytes.len() as u64 {
        check_records_from(path, bytes, summary_start as usize)?;
    }
    Ok(())
}

/// The pass of [`check_record_lengths`] over the records from byte `start` (0: the file's start,
/// magic included) to the footer.
fn check_records_from(path: &Path, bytes: &[u8], start: usize) -> Result<()> {
    use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
    let options = LinearReaderOptions::default()
        .with_record_length_limit(MAX_CHUNK_BYTES as usize)
        .with_skip_start_magic(start > 0);
    let mut reader = LinearReader::new_with_options(options);
    let mut offset = start;
    while let Some(event) = reader.next_event() {
        match event {
            Ok(LinearReadEvent::ReadRequest(_)) if offset == bytes.len() => {
                return Err(Error::Truncated {
                    path: path.to_path_buf(),
                    len: bytes.len() as u64,
                    problem: "the file ends inside a record".into(),
                });
            }
            Ok(LinearReadEvent::ReadRequest(n)) => {
                let n = n.min(bytes.len() - offset);
                reader.insert(n).copy_from_slice(&bytes[offset..offset + n]);
                reader.notify_read(n);
                offset += n;
            }
            Ok(LinearReadEvent::Record { opcode, data }) => {
                if opcode == mcap::records::op::ATTACHMENT && !attachment_holds_its_crc(data) {
                    return Err(Error::Corrupt {
                        path: path.to_path_buf(),
                        problem: "an attachment record ends before its CRC".into(),
                    });
                }
            }
            Err(e) => return Err(classify(path.to_path_buf(), bytes.len() as u64, &e)),
        }
    }
    Ok(())
}

/// Whether an attachment record's body holds the 4-byte CRC after its header and data length.
/// `mcap` 0.26's `parse_record` slices the body at `len - 4` without checking, so a body that
/// ends inside the CRC made `Summary::read` panic (found by the `mcap_recording` fuzz target).
/// A body too short for the header itself is `mcap`'s own (clean) error, so it passes here.
fn attachment_holds_its_crc(body: &[u8]) -> bool {
    // log_time u64, create_time u64, name (u32 length + bytes), media_type (the same), data_len u64
    let u32_at = |i: usize| -> Option<usize> {
        let b: [u8; 4] = body.get(i..i.checked_add(4)?)?.try_into().ok()?;
        Some(u32::from_le_bytes(b) as usize)
    };
    let header_len = u32_at(16)
        .and_then(|name| 20usize.checked_add(name))
        .and_then(|at| Some(at + 4 + u32_at(at)? + 8));
    match header_len {
        Some(n) if n <= body.len() => body.len() - n >= 4,
        _ => true,
    }
}

/// Maps an `mcap` read error to a structured error naming the file.
fn classify(path: PathBuf, len: u64, e: &mcap::McapError) -> Error {
    use mcap::McapError as E;
    match e {
        E::UnexpectedEof | E::BadFooter => Error::Truncated {
            path,
            len,
            problem: e.to_string(),
        },
        _ => Error::Corrupt {
            path,
            problem: e.to_string(),
        },
    }
}
