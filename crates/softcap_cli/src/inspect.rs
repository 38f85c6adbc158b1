//! `softcap inspect <verb> FILE`.

use std::io::Write;
use std::path::PathBuf;

use clap::{Args, Subcommand};
use prost_reflect::{DescriptorPool, DynamicMessage, SerializeOptions};
use softcap_app::{Error, IntoError, Result};
use softcap_mcap::Recording;

/// Look inside an .mcap file. The verb comes first: `softcap inspect summary capture.mcap`.
#[derive(Debug, Args)]
pub struct Inspect {
    #[command(subcommand)]
    pub verb: Verb,
}

#[derive(Debug, Subcommand)]
pub enum Verb {
    /// Profile, message count, time range, channels and provenance.
    Summary { file: PathBuf },
    /// One line per channel: topic, schema, message encoding, message count.
    Channels { file: PathBuf },
    /// Every message as one JSON line (protobuf decoded with the file's embedded schema).
    Dump {
        file: PathBuf,
        /// Only this topic.
        #[arg(long)]
        topic: Option<String>,
    },
    /// Content digest (SHA-256; ignores the provenance timestamp).
    Digest { file: PathBuf },
    /// Export a channel: markers/probe/simulated markers/scalars → CSV, meshes → OBJ or PLY.
    Export {
        file: PathBuf,
        /// `markers`, `probe`, `simulated`, `surface`, `volume`, or a topic name.
        #[arg(long)]
        what: String,
        /// Output file (`.csv`; `.obj` or `.ply` for meshes).
        #[arg(short, long)]
        output: PathBuf,
    },
    /// PNG time series of numeric fields of one channel, e.g.
    /// `softcap inspect plot capture.mcap --topic /capture/probe --field force_n.z -o f.png`.
    Plot {
        file: PathBuf,
        /// Channel to plot.
        #[arg(long)]
        topic: String,
        /// Field path (proto names): `force_n.z`, `markers[id=7].position_m.z`,
        /// `markers[0].reprojection_error_px`. Repeat for several series.
        #[arg(long = "field", required = true)]
        fields: Vec<String>,
        /// Field for the x axis instead of the log time in seconds.
        #[arg(long)]
        x: Option<String>,
        /// Output PNG.
        #[arg(short, long)]
        output: PathBuf,
    },
}

fn open(file: &PathBuf) -> Result<Recording> {
    Ok(Recording::open(file)?)
}

impl Inspect {
    pub fn run(&self) -> Result<()> {
        let stdout = std::io::stdout();
        let mut out = std::io::BufWriter::new(stdout.lock());
        match &self.verb {
            Verb::Summary { file } => {
                let r = open(file)?;
                let (count, range) = r.stats();
                writeln!(out, "file:      {}", file.display())?;
                writeln!(out, "messages:  {count}")?;
                if let Some((start, end)) = range {
                    writeln!(
                        out,
                        "time:      {:.6} s .. {:.6} s",
                        start as f64 * 1e-9,
                        end as f64 * 1e-9
                    )?;
                }
                writeln!(out, "chunks:    {}", r.summary().chunk_indexes.len())?;
                writeln!(out, "channels:  {}", r.channels().len())?;
                for c in r.channels() {
                    writeln!(
                        out,
                        "  {:<32} {:<28} {:>8}",
                        c.topic, c.schema_name, c.message_count
                    )?;
                }
                match r.provenance()? {
                    Some(p) => {
                        writeln!(out, "provenance:")?;
                        writeln!(out, "  stage:     {}", p.stage)?;
                        writeln!(out, "  version:   {}", p.crate_version)?;
                        writeln!(out, "  commit:    {}", p.git_commit)?;
                        writeln!(out, "  arguments: {}", p.arguments.join(" "))?;
                        writeln!(
                            out,
                            "  seed:      {}",
                            p.seed.map(|s| s.to_string()).unwrap_or_else(|| "-".into())
                        )?;
                        writeln!(out, "  written:   {}", p.timestamp)?;
                        for i in &p.inputs {
                            writeln!(out, "  input:     {} sha256:{}", i.path, i.sha256)?;
                        }
                    }
                    None => writeln!(out, "provenance: none")?,
                }
            }
            Verb::Channels { file } => {
                let r = open(file)?;
                writeln!(out, "topic\tschema\tmessage_encoding\tmessages")?;
                for c in r.channels() {
                    writeln!(
                        out,
                        "{}\t{}\t{}\t{}",
                        c.topic, c.schema_name, c.message_encoding, c.message_count
                    )?;
                }
            }
            Verb::Digest { file } => {
                let r = open(file)?;
                writeln!(out, "{}", r.digest()?)?;
            }
            Verb::Dump { file, topic } => {
                let r = open(file)?;
                dump(&r, topic.as_deref(), &mut out)?;
            }
            Verb::Export { file, what, output } => {
                let r = open(file)?;
                crate::export::export(&r, what, output)?;
            }
            Verb::Plot {
                file,
                topic,
                fields,
                x,
                output,
            } => {
                let r = open(file)?;
                let series = crate::plot::extract(&r, topic, fields, x.as_deref())?;
                let x_label = x.clone().unwrap_or_else(|| "log time [s]".into());
                crate::plot::draw(
                    &series,
                    &format!("{} — {topic}", file.display()),
                    &x_label,
                    output,
                )?;
                let n: usize = series.iter().map(|s| s.points.len()).sum();
                writeln!(
                    out,
                    "wrote {} ({} series, {n} points)",
                    output.display(),
                    series.len()
                )?;
            }
        }
        out.flush()?;
        Ok(())
    }
}

/// One decoded message.
pub(crate) struct Decoded {
    pub topic: String,
    pub log_time_ns: u64,
    pub schema: String,
    pub message: serde_json::Value,
}

/// Decodes the messages of `topic` (all topics when `None`) to JSON with the file's embedded
/// schemas. With `plain_fields`, proto field names are kept, default-valued fields are written
/// and 64-bit integers are numbers (what `plot` needs); otherwise the canonical proto3 JSON
/// mapping is used (what `dump` prints).
pub(crate) fn decode_messages(
    r: &Recording,
    topic: Option<&str>,
    plain_fields: bool,
) -> Result<Vec<Decoded>> {
    if let Some(t) = topic
        && r.channel(t).is_none()
    {
        return Err(Error::bad_input(format!(
            "{}: no channel `{t}`",
            r.path().display()
        )));
    }
    let options = SerializeOptions::new()
        .use_proto_field_name(plain_fields)
        .skip_default_fields(!plain_fields)
        .stringify_64_bit_integers(!plain_fields);
    let mut pools: std::collections::BTreeMap<String, Option<DescriptorPool>> = Default::default();
    let mut decoded = Vec::new();
    for m in r.messages()? {
        if topic.is_some_and(|t| t != m.topic) {
            continue;
        }
        let pool = pools.entry(m.topic.clone()).or_insert_with(|| {
            r.schema_of(&m.topic)
                .filter(|(_, enc, _)| enc == "protobuf")
                .and_then(|(_, _, data)| DescriptorPool::decode(data.as_slice()).ok())
        });
        let message = match (m.message_encoding.as_str(), pool) {
            ("protobuf", Some(pool)) => {
                let desc = pool.get_message_by_name(&m.schema_name).ok_or_else(|| {
                    Error::bad_input(format!(
                        "{}: schema `{}` not in its descriptor set",
                        r.path().display(),
                        m.schema_name
                    ))
                })?;
                let dynamic =
                    DynamicMessage::decode(desc, m.data.as_slice()).bad_input_with(|| {
                        format!(
                            "{}: `{}` at {} ns does not decode",
                            r.path().display(),
                            m.topic,
                            m.log_time_ns
                        )
                    })?;
                dynamic
                    .serialize_with_options(serde_json::value::Serializer, &options)
                    .failure_with(|| format!("{}: `{}` to JSON", r.path().display(), m.topic))?
            }
            ("json", _) => serde_json::from_slice(&m.data).unwrap_or_else(|_| {
                serde_json::Value::String(String::from_utf8_lossy(&m.data).into())
            }),
            _ => serde_json::json!({ "bytes": m.data.len() }),
        };
        decoded.push(Decoded {
            topic: m.topic.clone(),
            log_time_ns: m.log_time_ns,
            schema: m.schema_name.clone(),
            message,
        });
    }
    Ok(decoded)
}

/// Writes every message as `{"topic", "log_time_ns", "schema", "message"}` JSON lines.
fn dump(r: &Recording, topic: Option<&str>, out: &mut impl Write) -> Result<()> {
    for m in decode_messages(r, topic, false)? {
        let line = serde_json::json!({
            "topic": m.topic,
            "log_time_ns": m.log_time_ns,
            "schema": m.schema,
            "message": m.message,
        });
        writeln!(out, "{line}")?;
    }
    Ok(())
}
