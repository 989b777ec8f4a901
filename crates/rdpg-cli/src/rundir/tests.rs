use super::*;

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
