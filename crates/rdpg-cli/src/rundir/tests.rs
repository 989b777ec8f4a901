use super::*;
use rdpg_agents::UpdateStats;
use schema::UpdateMeans;

#[test]
fn evals_csv_is_read_back_and_bad_rows_are_named() {
    let dir = std::env::temp_dir().join(format!("rdpg-evals-csv-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let run = RunDir::new(&dir);
    let path = dir.join("evals.csv");
    std::fs::write(
        &path,
        format!("{EVALS_HEADER}25000,-12.5,3.25,0.1,86.550\n"),
    )
    .unwrap();
    let rows = run.read_evals_csv().unwrap();
    assert_eq!(rows.len(), 1);
    assert!(matches!(
        rows[0],
        Metric::Eval { step: 25000, mean_return, std_return, success_rate, wall }
            if (mean_return, std_return, success_rate, wall) == (-12.5, 3.25, 0.1, 86.55)
    ));
    for (text, needle) in [
        ("step,return\n".to_string(), "not an evals.csv"),
        (
            format!("{EVALS_HEADER}25000,-12.5,3.25,0.1\n"),
            "evals.csv:2: bad",
        ),
        (
            format!("{EVALS_HEADER}1,2,3,4,5\nx,2,3,4,5\n"),
            "evals.csv:3: bad",
        ),
    ] {
        std::fs::write(&path, text).unwrap();
        let err = format!("{:#}", run.read_evals_csv().unwrap_err());
        assert!(err.contains(needle), "{err}");
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

/// Learner-specific statistics go through `extra` by name: summed per name, averaged over the
/// updates that reported them; a `pending_updates.json` or metric row written with FORK's
/// earlier fixed fields reads into the same names.
#[test]
fn learner_specific_statistics_are_averaged_by_name_and_old_files_read_into_them() {
    let stats = |extra: &[(&str, f64)]| UpdateStats {
        critic_loss: 1.0,
        q_mean: 2.0,
        extra: extra.iter().map(|&(k, x)| (k.to_string(), x)).collect(),
        ..Default::default()
    };
    let mut sums = UpdateSums::default();
    sums.add(&stats(&[("model_loss", 0.5)]));
    sums.add(&stats(&[("model_loss", 1.5), ("fork_share", 1.0)]));
    sums.add(&stats(&[]));
    let saved: UpdateSums = serde_json::from_str(&serde_json::to_string(&sums).unwrap()).unwrap();
    assert_eq!(saved, sums);
    let means = sums.take();
    assert_eq!(means.updates, 3);
    assert_eq!(means.extra["model_loss"], 1.0);
    assert_eq!(means.extra["fork_share"], 1.0);
    let row = serde_json::to_value(&means).unwrap();
    assert_eq!(row["model_loss"], 1.0, "{row}");

    let old = r#"{"n":4,"n_actor":2,"critic":4.0,"actor":2.0,"q":8.0,"injected":0.0,
        "seconds":0.4,"n_model":4,"model":2.0,"n_fork_turn":2,"fork_used":1}"#;
    let mut old: UpdateSums = serde_json::from_str(old).unwrap();
    let means = old.take();
    assert_eq!(
        (means.extra["model_loss"], means.extra["fork_share"]),
        (0.5, 0.5)
    );
    let row = r#"{"updates":2,"critic_loss":1.0,"actor_loss":null,"q_mean":0.0,
        "injected_share":0.0,"update_ms":3.0,"model_loss":0.25,"fork_share":0.5}"#;
    let means: UpdateMeans = serde_json::from_str(row).unwrap();
    assert_eq!(
        (means.extra["model_loss"], means.extra["fork_share"]),
        (0.25, 0.5)
    );
}
