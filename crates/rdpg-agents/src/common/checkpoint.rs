//! Checkpoint file I/O shared by every learner and trainer: bincode state files, safetensors
//! maps, JSON files, and the header that versions a trainer checkpoint.
//!
//! A trainer checkpoint is a directory: `checkpoint.json` (this module's [`Header`]: format and
//! trainer kind), `train.json` (the run's [`TrainConfig`](crate::TrainConfig)),
//! `collector.bin` (environments, episodes in progress, counters), `loop.bin` (the
//! algorithm's own loop state) and `agent/` (the agent's networks and optimiser). The agent
//! directory alone is what `checkpoints/best` holds.
//!
//! Every file is flushed and its write errors returned. [`seal`] then fsyncs a finished
//! checkpoint directory and writes its `manifest.json` (size and CRC-32 of every file), which
//! [`verify`] checks before anything is loaded: a torn, truncated or bit-flipped checkpoint is
//! refused, naming the file, instead of resuming from garbage.

use std::collections::{BTreeMap, HashMap};
use std::io::Write;
use std::path::Path;

use serde::{Deserialize, Serialize};
use tch::Tensor;

use crate::error::{AgentError, Result};

/// The trainer checkpoint format this build writes and reads. Format 1 (rdpg 0.1, before the
/// re-cut of the agents crate) had no `checkpoint.json` and a different `loop.bin`; format 2
/// had no `manifest.json`, and its walkers kept one Box2D world across episodes, so their
/// episodes in progress cannot be rebuilt (see `rdpg_envs::WalkerConfig::fresh_world`).
/// Format 3 differs from 4 only by a field at the end of `replay.bin` (an episode in progress
/// the trainer never used), so it still loads ([`rdpg_core::replay::ReplayFormat3`]).
pub const TRAINER_FORMAT: u32 = 4;

/// The oldest trainer checkpoint format this build resumes.
pub const OLDEST_TRAINER_FORMAT: u32 = 3;

/// The most updates (or optimiser steps) a saved counter may claim: far beyond any run, and
/// far from where counting on would overflow.
pub const MAX_UPDATES: u64 = 1 << 48;

/// Refuses an update counter past [`MAX_UPDATES`], naming the file and the field.
pub fn check_counter(path: &Path, field: &str, v: u64) -> Result<()> {
    if v > MAX_UPDATES {
        return Err(ckpt_err(
            path,
            format!("{field} {v} is more than any run makes ({MAX_UPDATES})"),
        ));
    }
    Ok(())
}

/// A checkpoint error naming the file.
pub fn ckpt_err(path: &Path, e: impl std::fmt::Display) -> AgentError {
    AgentError::Checkpoint(format!("{}: {e}", path.display()))
}

/// Writes `value` with bincode; every write error (e.g. a full disk) is returned.
pub fn write_bin<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    let file = std::fs::File::create(path).map_err(|e| ckpt_err(path, e))?;
    let mut w = std::io::BufWriter::new(file);
    bincode::serialize_into(&mut w, value).map_err(|e| ckpt_err(path, e))?;
    w.flush().map_err(|e| ckpt_err(path, e))
}

/// The manifest of a sealed checkpoint directory.
pub const MANIFEST: &str = "manifest.json";

#[derive(Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
struct Manifest {
    /// Every file under the directory (paths relative to it, `/`-separated).
    files: BTreeMap<String, FileSeal>,
}

#[derive(Debug, Serialize, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
struct FileSeal {
    len: u64,
    crc32: u32,
}

fn walk(root: &Path, rel: &str, out: &mut Vec<String>) -> std::io::Result<()> {
    let mut entries: Vec<_> = std::fs::read_dir(root.join(rel))?.collect::<std::io::Result<_>>()?;
    entries.sort_by_key(|e| e.file_name());
    for e in entries {
        let name = e.file_name().to_string_lossy().into_owned();
        let path = if rel.is_empty() {
            name
        } else {
            format!("{rel}/{name}")
        };
        if e.file_type()?.is_dir() {
            walk(root, &path, out)?;
        } else if path != MANIFEST {
            out.push(path);
        }
    }
    Ok(())
}

fn file_seal(path: &Path) -> Result<FileSeal> {
    use std::io::Read;
    let mut f = std::fs::File::open(path).map_err(|e| ckpt_err(path, e))?;
    let (mut hasher, mut len) = (crc32fast::Hasher::new(), 0u64);
    let mut buf = vec![0u8; 1 << 20];
    loop {
        let k = f.read(&mut buf).map_err(|e| ckpt_err(path, e))?;
        if k == 0 {
            break;
        }
        hasher.update(&buf[..k]);
        len += k as u64;
    }
    Ok(FileSeal {
        len,
        crc32: hasher.finalize(),
    })
}

fn sync_path(path: &Path) -> Result<()> {
    std::fs::File::open(path)
        .and_then(|f| f.sync_all())
        .map_err(|e| ckpt_err(path, format!("cannot sync: {e}")))
}

/// Seals the finished checkpoint directory `dir`: fsyncs every file under it, writes
/// `manifest.json` with each file's size and CRC-32 (fsynced too), then fsyncs the
/// directories. Call it before moving the directory into place.
pub fn seal(dir: &Path) -> Result<()> {
    let mut files = Vec::new();
    walk(dir, "", &mut files).map_err(|e| ckpt_err(dir, e))?;
    let mut m = Manifest {
        files: BTreeMap::new(),
    };
    for f in files {
        let p = dir.join(&f);
        sync_path(&p)?;
        m.files.insert(f, file_seal(&p)?);
    }
    let path = dir.join(MANIFEST);
    let mut file = std::fs::File::create(&path).map_err(|e| ckpt_err(&path, e))?;
    file.write_all(serde_json::to_string_pretty(&m)?.as_bytes())
        .and_then(|_| file.sync_all())
        .map_err(|e| ckpt_err(&path, e))?;
    let mut dirs: Vec<&Path> = m
        .files
        .keys()
        .filter_map(|f| Path::new(f).parent())
        .chain([Path::new("")])
        .collect();
    dirs.sort();
    dirs.dedup();
    for d in dirs {
        sync_path(&dir.join(d))?;
    }
    Ok(())
}

/// Checks the checkpoint directory `dir` against its `manifest.json` (see [`seal`]): every
/// listed file present with its size and CRC-32, and no file missing from the list. A
/// directory without a manifest (written before rdpg sealed checkpoints) passes.
pub fn verify(dir: &Path) -> Result<()> {
    let path = dir.join(MANIFEST);
    if !path.exists() {
        return Ok(());
    }
    let m: Manifest = read_json(&path)?;
    let mut files = Vec::new();
    walk(dir, "", &mut files).map_err(|e| ckpt_err(dir, e))?;
    for f in &files {
        if !m.files.contains_key(f) {
            return Err(ckpt_err(
                &dir.join(f),
                "is not in the checkpoint's manifest.json",
            ));
        }
    }
    for (f, want) in &m.files {
        let p = dir.join(f);
        if !p.is_file() {
            return Err(ckpt_err(&p, "missing (listed in manifest.json)"));
        }
        let got = file_seal(&p)?;
        if got != *want {
            return Err(ckpt_err(
                &p,
                format!(
                    "is damaged: {} bytes with CRC-32 {:08x}, manifest.json says {} bytes with \
                     {:08x}",
                    got.len, got.crc32, want.len, want.crc32
                ),
            ));
        }
    }
    Ok(())
}

/// The agent format (RDPG's and PPO's `agent.json`) from which every saved agent directory is
/// sealed: without its `manifest.json` such an agent is refused. Format 1 agents were written
/// before or after sealing began, so one without a manifest loads with a warning, unless its
/// zoo entry's `summary.json` lists the manifest.
pub const SEALED_AGENT_FORMAT: u32 = 2;

/// [`verify`] for an agent directory (`agent.json`, weights): a missing `manifest.json` is
/// refused when the agent's format is [`SEALED_AGENT_FORMAT`] or later, or when the zoo entry
/// around it lists one in its `summary.json`; an older agent without one loads with a warning
/// naming it.
pub fn verify_agent(dir: &Path) -> Result<()> {
    if dir.join(MANIFEST).exists() {
        return verify(dir);
    }
    let meta = dir.join("agent.json");
    let format = read_json::<serde_json::Value>(&meta)?["format"]
        .as_u64()
        .unwrap_or(0);
    let listed = dir
        .parent()
        .and_then(|entry| std::fs::read_to_string(entry.join("summary.json")).ok())
        .is_some_and(|s| s.contains(&format!("agent/{MANIFEST}")));
    if format >= u64::from(SEALED_AGENT_FORMAT) || listed {
        return Err(ckpt_err(
            &dir.join(MANIFEST),
            if listed {
                "missing, though the entry's summary.json lists it: the agent's files cannot \
                 be checked"
            } else {
                "missing: every agent of this format is sealed, so its files cannot be checked"
            },
        ));
    }
    eprintln!(
        "warning: {} has no {MANIFEST} (an agent written before rdpg sealed agents): its files \
         are loaded unchecked",
        dir.display()
    );
    Ok(())
}

/// Reads a file written by [`write_bin`]; a missing, truncated or corrupt file is a
/// checkpoint error naming it.
pub fn read_bin<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T> {
    let file = std::fs::File::open(path).map_err(|e| ckpt_err(path, e))?;
    bincode::deserialize_from(std::io::BufReader::new(file))
        .map_err(|e| ckpt_err(path, format!("is truncated or corrupt: {e}")))
}

/// Writes `value` as pretty JSON; write errors are returned.
pub fn write_json<T: Serialize>(path: &Path, value: &T) -> Result<()> {
    std::fs::write(path, serde_json::to_string_pretty(value)?).map_err(|e| ckpt_err(path, e))
}

/// Reads a JSON file; a missing or malformed file is a checkpoint error naming it.
pub fn read_json<T: for<'de> Deserialize<'de>>(path: &Path) -> Result<T> {
    let text = std::fs::read_to_string(path).map_err(|e| ckpt_err(path, e))?;
    serde_json::from_str(&text).map_err(|e| ckpt_err(path, e))
}

/// Reads a safetensors file into a map by name; missing or corrupt files name the path.
pub fn read_tensors(path: &Path) -> Result<HashMap<String, Tensor>> {
    if !path.is_file() {
        return Err(ckpt_err(path, "missing"));
    }
    Ok(Tensor::read_safetensors(path)
        .map_err(|e| ckpt_err(path, format!("truncated or corrupt: {e}")))?
        .into_iter()
        .collect())
}

/// The number of values a safetensors file declares (the product of each tensor's shape,
/// summed), read from its header alone: nothing is allocated for the tensors. A header that
/// does not fit the file, or is not safetensors JSON, is an error naming the file.
pub fn declared_values(path: &Path) -> Result<f64> {
    use std::io::Read;
    let mut f = std::fs::File::open(path).map_err(|e| ckpt_err(path, e))?;
    let len = f.metadata().map_err(|e| ckpt_err(path, e))?.len();
    let mut n = [0u8; 8];
    f.read_exact(&mut n)
        .map_err(|_| ckpt_err(path, "truncated: no safetensors header"))?;
    let n = u64::from_le_bytes(n);
    if n > len.saturating_sub(8) || n > 100 << 20 {
        return Err(ckpt_err(
            path,
            format!("its header claims {n} bytes, the file has {len}"),
        ));
    }
    let mut header = vec![0u8; n as usize];
    f.read_exact(&mut header)
        .map_err(|_| ckpt_err(path, "truncated safetensors header"))?;
    let header: serde_json::Map<String, serde_json::Value> = serde_json::from_slice(&header)
        .map_err(|e| ckpt_err(path, format!("corrupt safetensors header: {e}")))?;
    Ok(header
        .iter()
        .filter(|(k, _)| *k != "__metadata__")
        .map(|(_, v)| {
            v["shape"].as_array().map_or(0.0, |s| {
                s.iter().map(|d| d.as_f64().unwrap_or(0.0)).product::<f64>()
            })
        })
        .sum())
}

/// Before any network is built from `meta` (its config): refuses a config whose networks
/// would hold more values (`expected`, computed without allocating) than the weights file
/// `weights` declares, so that a damaged or hand-made config cannot make the loader allocate
/// what the file could never fill. The shapes themselves are checked when the weights load.
pub fn check_sizes_against(weights: &Path, meta: &Path, expected: f64) -> Result<()> {
    let declared = declared_values(weights)?;
    if !(expected.is_finite() && expected <= declared) {
        return Err(ckpt_err(
            meta,
            format!(
                "describes networks of {expected:.0} values, but {} holds {declared:.0}: \
                 the config does not belong to these weights",
                weights.display()
            ),
        ));
    }
    Ok(())
}

/// Writes named tensors (copied to the CPU) as a safetensors file. A tensor holding NaN or
/// infinity is refused ([`AgentError::Diverged`], naming it) and nothing is written: a diverged
/// state never replaces a good checkpoint.
pub fn write_tensors(path: &Path, tensors: &[(String, Tensor)]) -> Result<()> {
    for (name, t) in tensors {
        if t.is_floating_point() && !bool::try_from(t.isfinite().all()).unwrap_or(false) {
            return Err(AgentError::Diverged(format!(
                "`{name}` holds non-finite values, so {} was not written",
                path.display()
            )));
        }
    }
    let cpu: Vec<(String, Tensor)> = tensors
        .iter()
        .map(|(n, t)| {
            (
                n.clone(),
                t.detach().to_device(tch::Device::Cpu).contiguous(),
            )
        })
        .collect();
    Tensor::write_safetensors(&cpu, path).map_err(|e| ckpt_err(path, e))
}

/// Which trainer wrote a checkpoint.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum TrainerKind {
    /// The off-policy trainer (RDPG, DDPG).
    OffPolicy,
    /// The on-policy PPO trainer.
    Ppo,
}

/// `checkpoint.json` of a trainer checkpoint.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Header {
    /// [`TRAINER_FORMAT`] of the build that wrote it.
    pub format: u32,
    /// The trainer that wrote it.
    pub trainer: TrainerKind,
}

impl Header {
    /// Writes the header of a checkpoint of `trainer` into `dir`.
    pub fn write(dir: &Path, trainer: TrainerKind) -> Result<()> {
        write_json(
            &dir.join("checkpoint.json"),
            &Header {
                format: TRAINER_FORMAT,
                trainer,
            },
        )
    }

    /// Reads the header of the checkpoint in `dir`. A checkpoint of an earlier format, or of
    /// another trainer than `expect` (when given), is refused with a message naming both.
    pub fn read(dir: &Path, expect: Option<TrainerKind>) -> Result<Self> {
        let path = dir.join("checkpoint.json");
        if !path.exists() && !dir.join("train.json").exists() {
            return Err(ckpt_err(
                dir,
                "holds no trainer checkpoint (neither checkpoint.json nor train.json)",
            ));
        }
        if !path.exists() {
            return Err(ckpt_err(
                dir,
                format!(
                    "written by an earlier rdpg (trainer checkpoint format 1); this build reads \
                     formats {OLDEST_TRAINER_FORMAT} to {TRAINER_FORMAT}. Its agent (`agent/`, and `checkpoints/best`) still \
                     loads for eval, render and record; to train further, start a new run"
                ),
            ));
        }
        let h: Header = read_json(&path)?;
        if !(OLDEST_TRAINER_FORMAT..=TRAINER_FORMAT).contains(&h.format) {
            return Err(ckpt_err(
                &path,
                format!(
                    "trainer checkpoint format {}, this build reads formats \
                     {OLDEST_TRAINER_FORMAT} to {TRAINER_FORMAT} \
                     (its agent, `agent/` and `checkpoints/best`, still loads for eval, render, \
                     zoo and record; to train further, start a new run)",
                    h.format
                ),
            ));
        }
        if let Some(want) = expect.filter(|&w| w != h.trainer) {
            return Err(ckpt_err(
                &path,
                format!("a {:?} checkpoint, expected {want:?}", h.trainer),
            ));
        }
        Ok(h)
    }
}

/// Copies the tensors named `{prefix}{variable name}` from `tensors` into the variables of
/// `vs` (converted to the variable's kind and device). A missing tensor or a shape mismatch
/// is a checkpoint error naming the tensor.
pub fn restore_vars(
    vs: &tch::nn::VarStore,
    tensors: &HashMap<String, Tensor>,
    prefix: &str,
) -> Result<()> {
    for (name, mut var) in crate::common::tensor::sorted_vars(vs) {
        let key = format!("{prefix}{name}");
        let src = tensors
            .get(&key)
            .ok_or_else(|| AgentError::Checkpoint(format!("missing weight `{key}`")))?;
        if src.size() != var.size() {
            return Err(AgentError::Checkpoint(format!(
                "weight `{key}` has shape {:?}, expected {:?}",
                src.size(),
                var.size()
            )));
        }
        tch::no_grad(|| var.copy_(&src.to_kind(var.kind()).to_device(var.device())));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A full disk (`/dev/full` fails every write with ENOSPC) is an error naming the file,
    /// for every writer: never a silent success with a truncated file.
    #[test]
    fn a_full_disk_is_an_error_naming_the_file() {
        let full = Path::new("/dev/full");
        if !full.exists() {
            return;
        }
        let big = vec![7u64; 100_000];
        for e in [
            write_bin(full, &big).unwrap_err(),
            write_json(full, &big).unwrap_err(),
            write_tensors(
                full,
                &[("w".into(), Tensor::zeros([1000], tch::kind::FLOAT_CPU))],
            )
            .unwrap_err(),
        ] {
            assert!(e.to_string().contains("/dev/full"), "{e}");
        }
    }

    /// `seal` then `verify`: a flipped byte, a truncated file, a missing file and an extra
    /// file are each refused, naming the file.
    #[test]
    fn verify_refuses_every_kind_of_damage() {
        let dir = std::env::temp_dir().join(format!("rdpg-seal-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(dir.join("agent")).unwrap();
        std::fs::write(dir.join("a.bin"), [1u8, 2, 3, 4]).unwrap();
        std::fs::write(dir.join("agent").join("w.bin"), [9u8; 64]).unwrap();
        seal(&dir).unwrap();
        verify(&dir).unwrap();
        let damage: [(&str, &dyn Fn()); 4] = [
            ("a.bin", &|| {
                std::fs::write(dir.join("a.bin"), [1u8, 2, 3, 5]).unwrap()
            }),
            ("a.bin", &|| {
                std::fs::write(dir.join("a.bin"), [1u8, 2, 3]).unwrap()
            }),
            ("w.bin", &|| {
                std::fs::remove_file(dir.join("agent").join("w.bin")).unwrap()
            }),
            ("x.bin", &|| {
                std::fs::write(dir.join("x.bin"), [0u8]).unwrap()
            }),
        ];
        for (name, hurt) in damage {
            let (a, w) = (
                std::fs::read(dir.join("a.bin")).unwrap(),
                std::fs::read(dir.join("agent").join("w.bin")).ok(),
            );
            hurt();
            let e = verify(&dir).unwrap_err().to_string();
            assert!(e.contains(name), "{name}: {e}");
            std::fs::write(dir.join("a.bin"), a).unwrap();
            if let Some(w) = w {
                std::fs::write(dir.join("agent").join("w.bin"), w).unwrap();
            }
            let _ = std::fs::remove_file(dir.join("x.bin"));
            verify(&dir).unwrap();
        }
        let _ = std::fs::remove_dir_all(&dir);
    }

    /// An agent without its manifest: refused from the sealed format on, or when its zoo
    /// entry lists one; an older agent loads (with a warning).
    #[test]
    fn agents_without_a_manifest_are_refused_unless_older_than_sealing() {
        let root = std::env::temp_dir().join(format!("rdpg-unsealed-{}", std::process::id()));
        let dir = root.join("agent");
        let _ = std::fs::remove_dir_all(&root);
        std::fs::create_dir_all(&dir).unwrap();
        std::fs::write(dir.join("agent.json"), r#"{"format": 1}"#).unwrap();
        verify_agent(&dir).unwrap();
        std::fs::write(
            root.join("summary.json"),
            r#"{"files": [["agent/manifest.json", 200]]}"#,
        )
        .unwrap();
        let e = verify_agent(&dir).unwrap_err().to_string();
        assert!(e.contains("summary.json lists it"), "{e}");
        std::fs::remove_file(root.join("summary.json")).unwrap();
        std::fs::write(dir.join("agent.json"), r#"{"format": 2}"#).unwrap();
        let e = verify_agent(&dir).unwrap_err().to_string();
        assert!(e.contains("every agent of this format is sealed"), "{e}");
        seal(&dir).unwrap();
        verify_agent(&dir).unwrap();
        std::fs::remove_dir_all(&root).unwrap();
    }
}
