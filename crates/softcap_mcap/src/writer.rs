//! The typed, atomic MCAP writer.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use softcap_app::AtomicFile;

use crate::catalog::{MESSAGE_ENCODING, SCHEMA_ENCODING, SoftcapMessage, Topic, descriptor_set};
use crate::error::{Error, Result};
use crate::provenance::{PROVENANCE_METADATA, Provenance};

/// Profile string in the MCAP header of softcap files.
pub const PROFILE: &str = "softcap";

struct ChannelEntry {
    id: u16,
    schema_name: String,
    sequence: u32,
}

/// Writes one softcap recording: zstd-compressed chunks, message indexes and a summary section.
///
/// Writes go to `NAME.mcap.PID-N.tmp` (a [`softcap_app::AtomicFile`]); [`Writer::finish`] writes the
/// summary, fsyncs and renames the file to `NAME.mcap`. A writer dropped without `finish` (an
/// error or panic in the stage) removes its temporary file, so a failed stage never leaves a
/// file that looks finished.
///
/// `log_time` is in nanoseconds since session start; static data goes at time 0
/// ([`Writer::write_static`]). The provenance record is written on creation.
pub struct Writer {
    path: PathBuf,
    inner: Option<mcap::Writer<AtomicFile>>,
    channels: BTreeMap<String, ChannelEntry>,
}

impl Writer {
    /// Starts `path` (writing a temporary file beside it) and records `provenance`.
    pub fn create(path: impl AsRef<Path>, provenance: &Provenance) -> Result<Self> {
        let path = path.as_ref().to_path_buf();
        if softcap_app::tmp_path(&path).is_err() {
            return Err(Error::BadOutputPath { path });
        }
        let file = AtomicFile::create(&path).map_err(|source| Error::Io {
            path: path.clone(),
            action: "creating",
            source,
        })?;
        let options = mcap::WriteOptions::new()
            .compression(Some(mcap::Compression::Zstd))
            .profile(PROFILE)
            .library(concat!("softcap_mcap/", env!("CARGO_PKG_VERSION")))
            .compression_threads(0)
            .emit_message_indexes(true)
            .emit_chunk_indexes(true)
            .emit_statistics(true)
            .emit_summary_offsets(true)
            .emit_metadata_indexes(true);
        // On error the AtomicFile is dropped, which removes NAME.mcap.PID-N.tmp.
        let inner = options.create(file).map_err(|source| Error::Write {
            path: path.clone(),
            source,
        })?;
        let mut writer = Self {
            path,
            inner: Some(inner),
            channels: BTreeMap::new(),
        };
        writer.write_metadata(PROVENANCE_METADATA, provenance.to_metadata())?;
        Ok(writer)
    }

    /// The final path (`NAME.mcap`).
    pub fn path(&self) -> &Path {
        &self.path
    }

    fn inner(&mut self) -> &mut mcap::Writer<AtomicFile> {
        self.inner
            .as_mut()
            .expect("inner writer is present until finish() consumes self")
    }

    fn write_err(&self, source: mcap::McapError) -> Error {
        Error::Write {
            path: self.path.clone(),
            source,
        }
    }

    fn channel_id(
        &mut self,
        topic: &str,
        schema_name: &str,
        schema_encoding: &str,
        schema_data: &[u8],
        message_encoding: &str,
    ) -> Result<u16> {
        if let Some(entry) = self.channels.get(topic) {
            if entry.schema_name != schema_name {
                return Err(Error::WrongSchema {
                    path: self.path.clone(),
                    topic: topic.into(),
                    expected: entry.schema_name.clone(),
                    found: schema_name.into(),
                    encoding: schema_encoding.into(),
                });
            }
            return Ok(entry.id);
        }
        let inner = self.inner();
        let added = inner
            .add_schema(schema_name, schema_encoding, schema_data)
            .and_then(|schema_id| {
                inner.add_channel(schema_id, topic, message_encoding, &BTreeMap::new())
            });
        let id = added.map_err(|e| self.write_err(e))?;
        self.channels.insert(
            topic.to_string(),
            ChannelEntry {
                id,
                schema_name: schema_name.to_string(),
                sequence: 0,
            },
        );
        Ok(id)
    }

    fn write_raw(
        &mut self,
        topic: &str,
        channel_id: u16,
        log_time_ns: u64,
        data: &[u8],
    ) -> Result<()> {
        let entry = self
            .channels
            .get_mut(topic)
            .expect("channel registered by channel_id()");
        let header = mcap::records::MessageHeader {
            channel_id,
            sequence: entry.sequence,
            log_time: log_time_ns,
            publish_time: log_time_ns,
        };
        entry.sequence = entry.sequence.wrapping_add(1);
        self.inner()
            .write_to_known_channel(&header, data)
            .map_err(|e| self.write_err(e))
    }

    /// Declares a channel without writing to it (so it appears, empty, in the summary).
    pub fn declare<M: SoftcapMessage>(&mut self, topic: &Topic<M>) -> Result<()> {
        self.channel_id(
            topic.name(),
            &M::schema_name(),
            SCHEMA_ENCODING,
            descriptor_set(),
            MESSAGE_ENCODING,
        )
        .map(|_| ())
    }

    /// Writes `message` on `topic` at `log_time_ns` (ns since session start).
    pub fn write<M: SoftcapMessage>(
        &mut self,
        topic: &Topic<M>,
        log_time_ns: u64,
        message: &M,
    ) -> Result<()> {
        let id = self.channel_id(
            topic.name(),
            &M::schema_name(),
            SCHEMA_ENCODING,
            descriptor_set(),
            MESSAGE_ENCODING,
        )?;
        let data = message.encode_to_vec();
        self.write_raw(topic.name(), id, log_time_ns, &data)
    }

    /// Writes static data (a mesh, a material table, calibration) on `topic` at time 0.
    pub fn write_static<M: SoftcapMessage>(&mut self, topic: &Topic<M>, message: &M) -> Result<()> {
        self.write(topic, 0, message)
    }

    /// Writes a Foxglove well-known message (e.g. a `/viz/...` twin built with [`crate::viz`]).
    pub fn write_foxglove<T: foxglove::Encode>(
        &mut self,
        topic: &str,
        log_time_ns: u64,
        message: &T,
    ) -> Result<()> {
        let schema = T::get_schema().ok_or_else(|| Error::Encode {
            path: self.path.clone(),
            topic: topic.into(),
            problem: "foxglove type has no schema".into(),
        })?;
        let id = self.channel_id(
            topic,
            &schema.name,
            &schema.encoding,
            &schema.data,
            &T::get_message_encoding(),
        )?;
        let mut data = Vec::with_capacity(message.encoded_len().unwrap_or(256));
        message.encode(&mut data).map_err(|e| Error::Encode {
            path: self.path.clone(),
            topic: topic.into(),
            problem: e.to_string(),
        })?;
        self.write_raw(topic, id, log_time_ns, &data)
    }

    /// Writes an MCAP metadata record.
    pub fn write_metadata(&mut self, name: &str, metadata: BTreeMap<String, String>) -> Result<()> {
        let record = mcap::records::Metadata {
            name: name.to_string(),
            metadata,
        };
        self.inner()
            .write_metadata(&record)
            .map_err(|e| self.write_err(e))
    }

    /// Writes the summary section, fsyncs, and renames `NAME.mcap.PID-N.tmp` to `NAME.mcap`.
    /// Returns the final path.
    pub fn finish(mut self) -> Result<PathBuf> {
        let mut inner = self
            .inner
            .take()
            .expect("inner writer is present until finish() consumes self");
        // On error the writer (and its AtomicFile) is dropped, which removes the tmp file.
        inner.finish().map_err(|e| self.write_err(e))?;
        inner.into_inner().commit().map_err(|source| Error::Io {
            path: self.path.clone(),
            action: "writing",
            source,
        })?;
        Ok(std::mem::take(&mut self.path))
    }
}

impl Drop for Writer {
    fn drop(&mut self) {
        // An unfinished writer (an error or panic in the stage): take the file without writing a
        // summary; dropping the AtomicFile removes NAME.mcap.PID-N.tmp.
        if let Some(inner) = self.inner.take() {
            drop(inner.into_inner());
        }
    }
}
