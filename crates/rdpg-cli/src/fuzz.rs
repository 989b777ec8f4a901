//! Fuzzing of every reader of a file that may come from someone else (built for `cargo test`
//! only): agent directories, trainer checkpoints, teacher files, `metrics.jsonl` on resume,
//! experiment files and the action files of `rdpg rollout`.
//!
//! Each reader gets valid files made by the real writers (tiny runs trained here), then
//! inputs made from them by mutation — bit flips, bytes and integers of interest (huge length
//! prefixes and sizes), truncations, cut and repeated chunks, numbers in text replaced by
//! absurd ones, deleted files — with the manifest (or a teacher file's own header) resealed
//! most of the time, so that the mutation reaches the parsing behind the checksum. Each input
//! runs the real loading code (and a first use of what it loaded: an action, a few training
//! steps, an environment step) under `catch_unwind`; an input that panics fails the test,
//! with its reader and number, which reproduce it (inputs are a function of both). An abort
//! cannot be caught: the input under way is in `rdpg-fuzz-<pid>/last-<reader>.txt` under
//! `/dev/shm` (or the temporary directory); an input that runs for a minute is reported as a
//! hang and aborts the run.
//!
//! `cargo test` tries 10 000 inputs per reader (`RDPG_FUZZ_INPUTS` sets another count,
//! `RDPG_FUZZ_ONLY=<reader>:<input>` replays one, `RDPG_FUZZ_SHOW=1` prints each refusal);
//! longer runs: `RDPG_FUZZ_INPUTS=200000 cargo test --release -p rdpg-cli fuzz -- --nocapture`.

#![cfg(test)]

use std::collections::BTreeMap;
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::path::{Path, PathBuf};
use std::sync::atomic::AtomicBool;
use std::sync::{Arc, OnceLock};
use std::time::{Duration, Instant};

use anyhow::Result;

use crate::experiment::Experiment;
use crate::rundir::{RunDir, RunLog, Which};

/// A small deterministic generator (splitmix64): inputs are a function of reader and number.
struct Rng(u64);

impl Rng {
    fn new(reader: &str, input: u64) -> Self {
        let h = reader.bytes().fold(0xcbf2_9ce4_8422_2325u64, |h, b| {
            (h ^ u64::from(b)).wrapping_mul(0x100_0000_01b3)
        });
        Self(h ^ input.wrapping_mul(0x9e37_79b9_7f4a_7c15))
    }
    fn next(&mut self) -> u64 {
        self.0 = self.0.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = self.0;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }
    /// Uniform in `0..n` (`n > 0`).
    fn below(&mut self, n: usize) -> usize {
        (self.next() % n as u64) as usize
    }
    fn chance(&mut self, p: f64) -> bool {
        ((self.next() >> 11) as f64 / (1u64 << 53) as f64) < p
    }
}

/// Integers that break size arithmetic: zero, sign and width boundaries, huge counts.
const INTEGERS: [u64; 16] = [
    0,
    1,
    0x7f,
    0xff,
    0x7fff,
    0xffff,
    0x7fff_ffff,
    0x8000_0000,
    0xffff_ffff,
    1 << 32,
    1 << 40,
    1 << 48,
    1 << 62,
    i64::MAX as u64,
    1 << 63,
    u64::MAX,
];

/// Replacements for a number in a text file.
const NUMBERS: [&str; 20] = [
    "0",
    "-1",
    "1e308",
    "-1e308",
    "1e999",
    "NaN",
    "nan",
    "inf",
    "-inf",
    "2000000000",
    "4294967296",
    "18446744073709551615",
    "18446744073709551616",
    "9223372036854775807",
    "-9223372036854775808",
    "1e-400",
    "0.5",
    "\"x\"",
    "[]",
    "null",
];

/// Spans of number tokens in `bytes` (a digit or a sign followed by digits, dots, exponents).
fn numbers(bytes: &[u8]) -> Vec<(usize, usize)> {
    let mut out = Vec::new();
    let mut i = 0;
    while i < bytes.len() {
        let starts = bytes[i].is_ascii_digit()
            || (bytes[i] == b'-' && bytes.get(i + 1).is_some_and(u8::is_ascii_digit));
        if starts && (i == 0 || !bytes[i - 1].is_ascii_alphanumeric()) {
            let mut j = i + 1;
            while j < bytes.len()
                && matches!(bytes[j], b'0'..=b'9' | b'.' | b'e' | b'E' | b'+' | b'-')
            {
                j += 1;
            }
            out.push((i, j));
            i = j;
        } else {
            i += 1;
        }
    }
    out
}

/// One to four mutations of `bytes`; `text` adds the number replacements.
fn mutate(rng: &mut Rng, bytes: &mut Vec<u8>, text: bool) {
    for _ in 0..1 + rng.below(4) {
        let len = bytes.len();
        let at = |rng: &mut Rng| rng.below(len.max(1));
        match if text && rng.chance(0.5) {
            8
        } else {
            rng.below(8)
        } {
            0 if len > 0 => {
                let i = at(rng);
                bytes[i] ^= 1 << rng.below(8);
            }
            1 if len > 0 => {
                let i = at(rng);
                bytes[i] = rng.next() as u8;
            }
            2 | 3 if len > 0 => {
                // An integer of interest, little-endian, 1 to 8 bytes wide (a length prefix,
                // a shape, a count), at an aligned offset half of the time.
                let width = [1, 2, 4, 8][rng.below(4)];
                let mut i = at(rng);
                if rng.chance(0.5) {
                    i -= i % width;
                }
                let v = INTEGERS[rng.below(INTEGERS.len())];
                for (k, b) in v.to_le_bytes().iter().take(width).enumerate() {
                    if let Some(x) = bytes.get_mut(i + k) {
                        *x = *b;
                    }
                }
            }
            4 => bytes.truncate(rng.below(len + 1)),
            5 if len > 0 => {
                let (i, n) = (at(rng), 1 + rng.below(64));
                bytes.drain(i..(i + n).min(len));
            }
            6 if len > 0 => {
                let (i, n) = (at(rng), 1 + rng.below(64));
                let chunk = bytes[i..(i + n).min(len)].to_vec();
                let j = rng.below(len + 1);
                bytes.splice(j..j, chunk);
            }
            7 => {
                let j = rng.below(len + 1);
                let extra: Vec<u8> = (0..1 + rng.below(16)).map(|_| rng.next() as u8).collect();
                bytes.splice(j..j, extra);
            }
            8 => {
                let spans = numbers(bytes);
                let v = NUMBERS[rng.below(NUMBERS.len())].as_bytes().to_vec();
                if spans.is_empty() {
                    let j = rng.below(len + 1);
                    bytes.splice(j..j, v);
                } else {
                    let (i, j) = spans[rng.below(spans.len())];
                    bytes.splice(i..j, v);
                }
            }
            _ => {}
        }
    }
}

/// Rewrites `dir/manifest.json` for the files now in `dir` (what a forger would do), without
/// the fsyncs of the real `seal`.
fn reseal(dir: &Path) -> Result<()> {
    let mut files = BTreeMap::new();
    for f in files_under(dir)?
        .into_iter()
        .filter(|f| f != "manifest.json")
    {
        let bytes = std::fs::read(dir.join(&f))?;
        let seal = serde_json::json!({ "len": bytes.len(), "crc32": crc32fast::hash(&bytes) });
        files.insert(f, seal);
    }
    std::fs::write(
        dir.join("manifest.json"),
        serde_json::to_string(&serde_json::json!({ "files": files }))?,
    )?;
    Ok(())
}

/// A teacher file's header rewritten for its (mutated) payload: its length and CRC-32.
fn reseal_teacher(bytes: &mut [u8]) {
    const HEADER: usize = 24;
    if bytes.len() >= HEADER && &bytes[..8] == b"rdpgTCH\n" {
        let len = (bytes.len() - HEADER) as u64;
        let crc = crc32fast::hash(&bytes[HEADER..]);
        bytes[12..20].copy_from_slice(&len.to_le_bytes());
        bytes[20..24].copy_from_slice(&crc.to_le_bytes());
    }
}

/// How to reseal a reader's files after a mutation.
#[derive(Clone, Copy, PartialEq)]
enum Seal {
    /// No checksum.
    None,
    /// The directory's `manifest.json`.
    Manifest,
    /// The teacher file's header.
    Teacher,
}

/// The loading code of a reader: the work directory, the file the input changed, the input's
/// generator.
type Load = Box<dyn Fn(&Path, &str, &mut Rng) -> Result<()>>;

/// A reader under test: a pristine directory, the files in it an input may change, and the
/// loading code (with a first use of what it loaded).
struct Reader {
    name: String,
    pristine: PathBuf,
    files: Vec<String>,
    seal: Seal,
    load: Load,
}

/// What the inputs of one reader did.
#[derive(Debug, Default)]
struct Tally {
    inputs: u64,
    loaded: u64,
    refused: u64,
    panics: Vec<String>,
    slowest: Duration,
    total: Duration,
}

fn is_text(file: &str) -> bool {
    [".json", ".jsonl", ".toml", ".csv", ".txt"]
        .iter()
        .any(|e| file.ends_with(e))
}

fn copy_dir(from: &Path, to: &Path) -> Result<()> {
    std::fs::create_dir_all(to)?;
    for e in std::fs::read_dir(from)? {
        let e = e?;
        if e.file_type()?.is_dir() {
            copy_dir(&e.path(), &to.join(e.file_name()))?;
        } else {
            std::fs::copy(e.path(), to.join(e.file_name()))?;
        }
    }
    Ok(())
}

/// Every file under `dir` (relative paths).
fn files_under(dir: &Path) -> Result<Vec<String>> {
    fn walk(root: &Path, rel: &str, out: &mut Vec<String>) -> Result<()> {
        for e in std::fs::read_dir(root.join(rel))? {
            let e = e?;
            let name = e.file_name().to_string_lossy().into_owned();
            let path = if rel.is_empty() {
                name
            } else {
                format!("{rel}/{name}")
            };
            if e.file_type()?.is_dir() {
                walk(root, &path, out)?;
            } else {
                out.push(path);
            }
        }
        Ok(())
    }
    let mut out = Vec::new();
    walk(dir, "", &mut out)?;
    out.sort();
    Ok(out)
}

/// How long one input may run before the fuzzer calls it a hang.
const HANG: Duration = Duration::from_secs(60);

fn fuzz(r: &Reader, inputs: u64) -> Result<Tally> {
    let work = r.pristine.with_extension("work");
    let _ = std::fs::remove_dir_all(&work);
    copy_dir(&r.pristine, &work)?;
    let last = corpus().root.join(format!("last-{}.txt", r.name));
    let mut sealed: Vec<&str> = r
        .files
        .iter()
        .filter_map(|f| f.strip_suffix("manifest.json"))
        .collect();
    sealed.sort_by_key(|d| std::cmp::Reverse(d.len()));
    // An input that runs for minutes is a hang: say which, and abort rather than hold CI.
    let (watch, watched) = std::sync::mpsc::channel::<Option<String>>();
    let watchdog = std::thread::spawn(move || {
        let mut case = None;
        loop {
            match watched.recv_timeout(HANG) {
                Ok(Some(c)) => case = Some(c),
                Ok(None) => case = None,
                Err(std::sync::mpsc::RecvTimeoutError::Disconnected) => return,
                Err(std::sync::mpsc::RecvTimeoutError::Timeout) => {
                    if let Some(c) = case.take() {
                        eprintln!("fuzz: {c} ran for more than {HANG:?}: a hang");
                        std::process::abort();
                    }
                }
            }
        }
    });
    let mut t = Tally::default();
    let began = Instant::now();
    // `RDPG_FUZZ_ONLY=<reader>:<input>` replays one input (e.g. one that aborted).
    let only = std::env::var("RDPG_FUZZ_ONLY").ok();
    let only = only.as_deref().and_then(|o| o.split_once(':'));
    let range = match only {
        Some((name, k)) if name == r.name => k.parse().map_or(0..0, |k: u64| k..k + 1),
        Some(_) => 0..0,
        None => 0..inputs,
    };
    for input in range {
        let mut rng = Rng::new(&r.name, input);
        let file = &r.files[rng.below(r.files.len())];
        let mut bytes = std::fs::read(r.pristine.join(file))?;
        let removed = rng.chance(0.02);
        if removed {
            std::fs::remove_file(work.join(file))?;
        } else {
            mutate(&mut rng, &mut bytes, is_text(file));
            if r.seal == Seal::Teacher && rng.chance(0.85) {
                reseal_teacher(&mut bytes);
            }
            std::fs::write(work.join(file), &bytes)?;
        }
        if r.seal == Seal::Manifest && !file.ends_with("manifest.json") && rng.chance(0.85) {
            // Innermost first: a checkpoint's manifest lists its agent's.
            for d in &sealed {
                reseal(&work.join(d))?;
            }
        }
        let case = format!("reader {} input {input}: {file}", r.name);
        std::fs::write(&last, format!("{case}\n"))?;
        let _ = watch.send(Some(case));
        let started = Instant::now();
        let outcome = catch_unwind(AssertUnwindSafe(|| (r.load)(&work, file, &mut rng)));
        let _ = watch.send(None);
        t.slowest = t.slowest.max(started.elapsed());
        t.inputs += 1;
        match outcome {
            Ok(Ok(())) => t.loaded += 1,
            Ok(Err(e)) => {
                t.refused += 1;
                if std::env::var_os("RDPG_FUZZ_SHOW").is_some() {
                    eprintln!("{} {input} {file}: {e:#}", r.name);
                }
            }
            Err(p) => {
                let msg = p
                    .downcast_ref::<String>()
                    .cloned()
                    .or_else(|| p.downcast_ref::<&str>().map(|s| (*s).to_string()))
                    .unwrap_or_default();
                t.panics.push(format!("input {input} ({file}): {msg}"));
            }
        }
        // Back to the pristine files for the next input: the changed file and the manifests
        // (readers of sealed directories write nothing), or the whole directory (a resume
        // rewrites its metric files).
        if r.seal == Seal::Manifest {
            for f in sealed
                .iter()
                .map(|d| format!("{d}manifest.json"))
                .chain([file.clone()])
            {
                std::fs::copy(r.pristine.join(&f), work.join(&f))?;
            }
        } else {
            let _ = std::fs::remove_dir_all(&work);
            copy_dir(&r.pristine, &work)?;
        }
    }
    t.total = began.elapsed();
    drop(watch);
    let _ = watchdog.join();
    let _ = std::fs::remove_file(&last);
    Ok(t)
}

fn inputs() -> u64 {
    std::env::var("RDPG_FUZZ_INPUTS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10_000)
}

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../..")
        .join(path)
}

/// The valid files the readers start from, made once by the real writers.
struct Corpus {
    root: PathBuf,
}

/// Tiny runs: an LSTM agent (RDPG on the cue task), a feed-forward one (DDPG on Pendulum)
/// and PPO, each trained a few hundred steps, checkpointed and shipped as a zoo-like entry
/// (`config.toml` and `agent/`); a teacher file recorded from the first.
fn corpus() -> &'static Corpus {
    static CORPUS: OnceLock<Corpus> = OnceLock::new();
    CORPUS.get_or_init(|| {
        // In memory where there is a tmpfs: an input is a few file writes and removals.
        let shm = Path::new("/dev/shm");
        let tmp = if shm.is_dir() {
            shm.to_path_buf()
        } else {
            std::env::temp_dir()
        };
        // Corpora of earlier test processes that have ended are removed.
        for e in std::fs::read_dir(&tmp).into_iter().flatten().flatten() {
            let name = e.file_name().to_string_lossy().into_owned();
            if let Some(pid) = name.strip_prefix("rdpg-fuzz-") {
                if !Path::new("/proc").join(pid).exists() {
                    let _ = std::fs::remove_dir_all(e.path());
                }
            }
        }
        let root = tmp.join(format!("rdpg-fuzz-{}", std::process::id()));
        make_corpus(&root).expect("the fuzz corpus is made by the real writers");
        Corpus { root }
    })
}

const PPO: &str = r#"
name = "fuzz-ppo"
algo = "ppo"
[train]
env = "Pendulum-v1"
total_steps = 400
eval_every = 400
eval_episodes = 1
[ppo]
hidden = [16]
rollout_steps = 128
epochs = 1
minibatch_size = 64
num_threads = 1
"#;

fn kinds() -> [(&'static str, Experiment); 4] {
    let load = |p: &str, sets: &[&str]| {
        let sets: Vec<String> = sets.iter().map(|s| (*s).to_string()).collect();
        Experiment::load(&repo(p), &sets).expect("a shipped config")
    };
    let ppo = toml::from_str::<Experiment>(PPO).expect("the PPO config");
    [
        (
            "lstm",
            load(
                "configs/cue-rdpg.toml",
                &[
                    "train.total_steps=300",
                    "off_policy.warmup_steps=200",
                    "agent.batch_size=8",
                ],
            ),
        ),
        (
            "ff",
            load(
                "configs/memory-ddpg.toml",
                &[
                    "train.total_steps=300",
                    "off_policy.warmup_steps=200",
                    "agent.batch_size=8",
                    "agent.actor_hidden=16",
                    "agent.critic_hidden=16",
                    "agent.trunk={ mlp = { hidden = [16] } }",
                ],
            ),
        ),
        (
            "sac",
            load(
                "configs/memory-sac.toml",
                &[
                    "train.total_steps=300",
                    "off_policy.warmup_steps=200",
                    "agent.batch_size=8",
                    "agent.actor_hidden=16",
                    "agent.critic_hidden=16",
                ],
            ),
        ),
        ("ppo", ppo),
    ]
}

fn make_corpus(root: &Path) -> Result<()> {
    let _ = std::fs::remove_dir_all(root);
    for (kind, exp) in kinds() {
        let mut t = rdpg_agents::new_trainer(exp.train.clone(), exp.learner())?;
        t.run(exp.train.total_steps, &mut rdpg_agents::Quiet)?;
        t.save(&root.join(format!("checkpoint-{kind}")))?;
        let entry = root.join(format!("agent-{kind}"));
        std::fs::create_dir_all(&entry)?;
        std::fs::write(entry.join("config.toml"), exp.to_toml()?)?;
        t.save_agent(&entry.join("agent"))?;
    }
    // A teacher file from the LSTM agent, and the run directory its student resumes.
    let entry = root.join("agent-lstm");
    let (exp, mut policy) = RunDir::new(&entry).policy(Which::Best)?;
    let info = rdpg_agents::rdpg::inject::TeacherInfo {
        run: entry.display().to_string(),
        name: exp.name.clone(),
        algo: exp.algo.as_str().into(),
        checkpoint: "best".into(),
        train_reward: String::new(),
        test: None,
    };
    let t = rdpg_agents::rdpg::inject::record(policy.as_mut(), &exp.train, 3, 7, 0.1, info)?;
    std::fs::create_dir_all(root.join("teacher"))?;
    t.save(&root.join("teacher/teacher.bin"))?;
    // A run's metric files, as a resume reads them.
    let run = root.join("metrics");
    std::fs::create_dir_all(&run)?;
    let mut jsonl = String::new();
    for k in 1..=12u64 {
        let row = if k % 4 == 0 {
            crate::rundir::Metric::Eval {
                step: 50 * k,
                mean_return: -0.5 + k as f64 * 0.1,
                std_return: 0.25,
                success_rate: 0.5,
                wall: k as f64,
            }
        } else {
            crate::rundir::Metric::Episode {
                step: 50 * k,
                ret: k as f64 * 0.1,
                stock_return: k as f64 * 0.1,
                len: 50,
                success: k % 3 == 0,
                r100: (k > 5).then_some(0.3),
                wall: k as f64,
                learner: Default::default(),
            }
        };
        jsonl.push_str(&serde_json::to_string(&row)?);
        jsonl.push('\n');
    }
    std::fs::write(run.join("metrics.jsonl"), jsonl)?;
    std::fs::write(run.join("config.toml"), exp.to_toml()?)?;
    // Experiment files: every shipped config.
    let configs = root.join("configs");
    std::fs::create_dir_all(&configs)?;
    for e in std::fs::read_dir(repo("configs"))? {
        let e = e?;
        std::fs::copy(e.path(), configs.join(e.file_name()))?;
    }
    // An action file of `rdpg rollout` for a walker.
    std::fs::create_dir_all(root.join("actions"))?;
    let mut text = String::from("# hip, knee, hip, knee\n");
    for k in 0..40 {
        let x = (k as f32 * 0.3).sin();
        text.push_str(&format!("{x}, {}, {}, -0.5\n", -x, x * 0.5));
    }
    std::fs::write(root.join("actions/actions.csv"), text)?;
    Ok(())
}

fn reader(name: &str, dir: &str, seal: Seal, load: Load) -> Reader {
    let pristine = corpus().root.join(dir);
    let files = files_under(&pristine).expect("the corpus");
    Reader {
        name: name.into(),
        pristine,
        files,
        seal,
        load,
    }
}

/// An agent directory as `rdpg eval --run`, `Policy.load` and `rdpg record` read it, and
/// its first actions (on a zero and on a huge observation).
fn agent_reader(kind: &str) -> Reader {
    reader(
        &format!("agent-{kind}"),
        &format!("agent-{kind}"),
        Seal::Manifest,
        Box::new(|dir, _, _| {
            let (exp, mut policy) = RunDir::new(dir).policy(Which::Best)?;
            let env = rdpg_envs::make_with(&exp.train.env, &exp.train.env_options())?;
            let dim = env.observation_space().dim();
            policy.begin_episode();
            policy.act(&vec![0.0; dim])?;
            // Refused by a recurrent agent (its state would overflow), acted on by others.
            let _ = policy.act(&vec![1e38; dim]);
            Ok(())
        }),
    )
}

/// A trainer checkpoint as `rdpg train --resume` reads it, then a few steps of training.
fn checkpoint_reader(kind: &str) -> Reader {
    let mut r = reader(
        &format!("checkpoint-{kind}"),
        &format!("checkpoint-{kind}"),
        Seal::Manifest,
        Box::new(|dir, _, _| {
            let mut t = rdpg_agents::load_trainer(dir)?;
            let to = t.steps() + 4;
            t.set_total_steps(to);
            t.run(to, &mut rdpg_agents::Quiet)?;
            Ok(())
        }),
    );
    // The agent's own files are the agent reader's; these are the trainer's.
    r.files
        .retain(|f| !f.starts_with("agent/") || f.ends_with(".json"));
    r
}

fn check(t: &Tally, name: &str) {
    eprintln!(
        "fuzz {name}: {} inputs in {:.1} s, {} loaded, {} refused, {} panics, slowest {:.1} ms",
        t.inputs,
        t.total.as_secs_f64(),
        t.loaded,
        t.refused,
        t.panics.len(),
        t.slowest.as_secs_f64() * 1e3
    );
    assert!(
        t.panics.is_empty(),
        "{name}: {} panics:\n{}",
        t.panics.len(),
        t.panics.join("\n")
    );
    assert!(
        t.refused > 0 || t.inputs < 100,
        "{name}: no input was refused: the mutations reach nothing"
    );
}

fn run_reader(r: Reader) {
    let t = fuzz(&r, inputs()).expect("the fuzzer's own files");
    check(&t, &r.name);
}

#[test]
fn fuzz_agent_directories() {
    for kind in ["lstm", "ff", "sac", "ppo"] {
        run_reader(agent_reader(kind));
    }
}

#[test]
fn fuzz_trainer_checkpoints() {
    for kind in ["lstm", "ff", "sac", "ppo"] {
        run_reader(checkpoint_reader(kind));
    }
}

#[test]
fn fuzz_teacher_files() {
    let student = kinds()[0].1.train.clone();
    run_reader(reader(
        "teacher",
        "teacher",
        Seal::Teacher,
        Box::new(move |dir, _, _| {
            let path = dir.join("teacher.bin");
            rdpg_agents::rdpg::inject::TeacherFile::load(&path)?.episodes_for(&student, &path)?;
            crate::rundir::TeacherSummary::read(&path)?;
            Ok(())
        }),
    ));
}

#[test]
fn fuzz_metrics_on_resume() {
    run_reader(reader(
        "metrics",
        "metrics",
        Seal::None,
        Box::new(|dir, _, rng| {
            let upto = [0, 100, 400, u64::MAX][rng.below(4)];
            let stop = Arc::new(AtomicBool::new(false));
            RunLog::open(&RunDir::new(dir), upto, 1000, true, stop)?;
            Ok(())
        }),
    ));
}

#[test]
fn fuzz_experiment_files() {
    let mut r = reader(
        "config",
        "configs",
        Seal::None,
        Box::new(|dir, file, _| {
            let exp = Experiment::load(&dir.join(file), &[])?;
            crate::experiment::check_memory(&exp)?;
            Ok(())
        }),
    );
    r.files.retain(|f| f.ends_with(".toml"));
    run_reader(r);
}

#[test]
fn fuzz_action_files() {
    run_reader(reader(
        "actions",
        "actions",
        Seal::None,
        Box::new(|dir, _, _| {
            let mut env = rdpg_envs::make("BipedalWalker-v3")?;
            let text = std::fs::read_to_string(dir.join("actions.csv"))?;
            let actions = crate::rollout::parse_actions(&text, env.action_space().dim())?;
            env.reset(Some(0))?;
            for a in actions.iter().take(8) {
                env.step(a)?;
            }
            Ok(())
        }),
    ));
}
