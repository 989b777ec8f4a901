//! End-to-end tests of the `rdpg` binary.

use std::path::PathBuf;
use std::process::Command;

use serde_json::Value;

fn rdpg() -> Command {
    Command::new(env!("CARGO_BIN_EXE_rdpg"))
}

/// Output of a successful run (panics with its stderr otherwise).
fn ok(cmd: &mut Command) -> std::process::Output {
    let out = cmd.output().unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    out
}

fn tmp(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("rdpg-cli-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    dir.join(name)
}

/// `rdpg rollout` reproduces a Gymnasium trace through its JSON-lines contract, with numbers
/// that parse back to the exact f32 / f64 values.
#[test]
fn rollout_reproduces_a_gymnasium_trace() {
    let fixture = PathBuf::from(env!("CARGO_MANIFEST_DIR"))
        .join("../../tests/fixtures/traces/hardcore_random_fall.json");
    let trace: Value = serde_json::from_str(&std::fs::read_to_string(fixture).unwrap()).unwrap();
    let ep = &trace["episodes"][0];
    let actions = ep["actions"].as_array().unwrap();
    let text: String = actions
        .iter()
        .map(|a| {
            let v: Vec<String> = a
                .as_array()
                .unwrap()
                .iter()
                .map(|x| (x.as_f64().unwrap() as f32).to_string())
                .collect();
            v.join(",") + "\n"
        })
        .collect();
    let file = tmp("actions.csv");
    std::fs::write(&file, text).unwrap();
    let out = ok(rdpg()
        .args([
            "rollout",
            "--env",
            trace["env_id"].as_str().unwrap(),
            "--seed",
        ])
        .arg(ep["seed"].as_u64().unwrap().to_string())
        .arg("--actions")
        .arg(&file));
    let lines: Vec<Value> = String::from_utf8(out.stdout)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(lines.len(), actions.len() + 1);
    let f32s = |v: &Value| -> Vec<f32> {
        v.as_array()
            .unwrap()
            .iter()
            .map(|x| x.as_f64().unwrap() as f32)
            .collect()
    };
    for (k, line) in lines.iter().enumerate() {
        assert_eq!(line["step"].as_u64().unwrap() as usize, k);
        assert_eq!(f32s(&line["obs"]), f32s(&ep["obs"][k]), "obs at step {k}");
        if k > 0 {
            assert_eq!(
                line["reward"].as_f64().unwrap(),
                ep["rewards"][k - 1].as_f64().unwrap()
            );
            assert_eq!(line["terminated"], ep["terminated"][k - 1]);
            assert_eq!(line["truncated"], ep["truncated"][k - 1]);
        } else {
            assert!(line.get("reward").is_none());
        }
    }
    assert_eq!(lines.last().unwrap()["terminated"], Value::Bool(true));
}

#[test]
fn rollout_rejects_bad_input_with_a_message() {
    let file = tmp("bad.csv");
    std::fs::write(&file, "0,0,0\n").unwrap();
    let out = rdpg()
        .args([
            "rollout",
            "--env",
            "BipedalWalker-v3",
            "--seed",
            "0",
            "--actions",
        ])
        .arg(&file)
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(err.contains("line 1") && err.contains("3 numbers"), "{err}");
    let out = rdpg()
        .args(["rollout", "--env", "Nope-v0", "--seed", "0", "--actions"])
        .arg(&file)
        .output()
        .unwrap();
    assert!(!out.status.success());
    assert!(String::from_utf8_lossy(&out.stderr).contains("unknown environment id"));
}

#[test]
fn render_writes_a_gif_and_pngs() {
    let gif = tmp("walker.gif");
    let pngs = tmp("frames");
    let out = ok(rdpg()
        .args([
            "render",
            "--env",
            "BipedalWalkerHardcore-v3",
            "--seed",
            "1",
            "--max-steps",
            "12",
            "--every",
            "4",
            "--gif",
        ])
        .arg(&gif)
        .arg("--png-dir")
        .arg(&pngs));
    let bytes = std::fs::read(&gif).unwrap();
    assert_eq!(&bytes[..6], b"GIF89a");
    assert_eq!(
        std::fs::read_dir(&pngs).unwrap().count(),
        4,
        "frames 0, 4, 8, 12"
    );
    assert!(String::from_utf8_lossy(&out.stdout).contains("return"));
}

#[test]
fn bench_env_prints_one_json_line_ending_in_steps_per_sec() {
    for extra in [&[][..], &["--workers", "2"][..]] {
        let out = ok(rdpg()
            .args([
                "bench",
                "env",
                "--env",
                "BipedalWalker-v3",
                "--steps",
                "400",
            ])
            .args(extra));
        let text = String::from_utf8(out.stdout).unwrap();
        let line = text.trim();
        assert_eq!(text.lines().count(), 1);
        let v: Value = serde_json::from_str(line).unwrap();
        assert!(v["steps_per_sec"].as_f64().unwrap() > 0.0);
        let tail = line.rsplit_once(",\"steps_per_sec\":").unwrap().1;
        assert!(tail.ends_with('}') && !tail.contains(','), "{line}");
    }
}

#[test]
fn bench_update_prints_one_json_line_ending_in_updates_per_sec() {
    let out = ok(rdpg().args([
        "bench",
        "update",
        "--iters",
        "2",
        "--batch",
        "4",
        "--scan",
        "3",
        "--opt",
        "2",
        "--threads",
        "1",
    ]));
    let text = String::from_utf8(out.stdout).unwrap();
    let v: Value = serde_json::from_str(text.trim()).unwrap();
    assert!(v["updates_per_sec"].as_f64().unwrap() > 0.0);
    assert!(
        text.trim().ends_with('}') && text.trim().rsplit_once(",\"updates_per_sec\":").is_some()
    );
    let bad = rdpg()
        .args(["bench", "update", "--device", "tpu"])
        .output()
        .unwrap();
    assert!(!bad.status.success());
    assert!(String::from_utf8_lossy(&bad.stderr).contains("--device"));
}
