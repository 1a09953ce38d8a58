//! What can be checked without numpy: the argument names, the exception classes and
//! the report's Python values (the package itself is tested by pytest, tests/).
use super::*;

#[test]
fn names_of_units_and_frames() {
    assert_eq!(parse_units("mm").ok(), Some(Units::Millimetres));
    assert_eq!(parse_frame("optical").ok(), Some(InputFrame::Optical));
    assert_eq!(parse_frame("body").ok(), Some(InputFrame::Body));
    Python::initialize();
    Python::attach(|py| {
        let e = parse_units("km").unwrap_err();
        assert!(e.is_instance_of::<PyValueError>(py));
        assert_eq!(
            e.value(py).to_string(),
            "units=\"km\": expected \"m\" or \"mm\""
        );
        assert!(parse_frame("world").is_err());
    });
}

#[test]
fn file_errors_are_os_errors_unless_the_file_opens() {
    Python::initialize();
    let dir = std::env::temp_dir().join(format!("epd-py-test-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let file = dir.join("a.ply");
    std::fs::write(&file, b"not a cloud").unwrap();
    Python::attach(|py| {
        let missing = file_error(&dir.join("missing.ply"), "cannot read: x".into());
        // Python picks the subclass from the errno when the exception is made.
        let v = missing.value(py);
        assert!(v.is_instance_of::<pyo3::exceptions::PyFileNotFoundError>());
        assert_eq!(v.getattr("strerror").unwrap().to_string(), "cannot read: x");
        let d = file_error(&dir, "not a regular file".into());
        assert!(d.is_instance_of::<PyIsADirectoryError>(py));
        let bad = file_error(&file, "PLY: bad".into());
        assert!(bad.is_instance_of::<PyValueError>(py));
        assert!(!bad.is_instance_of::<PyOSError>(py));
    });
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn report_values_keep_their_types() {
    Python::initialize();
    Python::attach(|py| {
        let fields = [
            ("file", Field::Text("f.ply".into())),
            ("n", Field::Int(3)),
            ("x", Field::Num(508.0)),
            ("nan", Field::Num(f64::NAN)),
            ("b", Field::Bool(true)),
            ("none", Field::Null),
        ];
        let d = fields_dict(py, &fields, true).unwrap();
        let keys: Vec<String> = d.keys().extract().unwrap();
        assert_eq!(keys, ["file", "n", "x", "nan", "b", "none"]);
        let get = |k: &str| d.get_item(k).unwrap().unwrap();
        assert!(get("file").is_none(), "an array has no file");
        assert_eq!(get("n").extract::<i64>().unwrap(), 3);
        assert!(get("x").is_instance_of::<pyo3::types::PyFloat>());
        assert!(get("nan").is_none());
        assert!(get("b").extract::<bool>().unwrap());
        let d = fields_dict(py, &fields, false).unwrap();
        assert_eq!(d.get_item("file").unwrap().unwrap().to_string(), "f.ply");
    });
}
