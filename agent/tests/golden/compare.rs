//! Reading the golden JSON files (`{shape, data}` tensors, `{name: {shape, data}}`
//! parameter sets) and comparing with the float32 tolerances of the golden tests:
//! 1e-5 absolute plus 1e-5 relative.
#![allow(dead_code, unreachable_pub, reason = "each test file uses a subset")]

use agent::core::nets::NamedArray;
use serde_json::Value;
use tch::{Kind, Tensor};

/// The golden file `tests/golden/{name}.json`.
pub fn golden(name: &str) -> Value {
    let path = format!("{}/tests/golden/{name}.json", env!("CARGO_MANIFEST_DIR"));
    serde_json::from_str(&std::fs::read_to_string(&path).expect("golden file")).expect("valid json")
}

/// A `{shape, data}` object as an f32 tensor.
pub fn tensor(v: &Value) -> Tensor {
    let shape: Vec<i64> = v["shape"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_i64().unwrap())
        .collect();
    let data: Vec<f32> = v["data"]
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap() as f32)
        .collect();
    Tensor::from_slice(&data).reshape(shape.as_slice())
}

/// A list of numbers as a 1-d f32 tensor.
pub fn vector(v: &Value) -> Tensor {
    let data: Vec<f32> = v
        .as_array()
        .unwrap()
        .iter()
        .map(|x| x.as_f64().unwrap() as f32)
        .collect();
    Tensor::from_slice(&data)
}

/// A number.
pub fn scalar(v: &Value) -> f64 {
    v.as_f64().unwrap()
}

/// Elementwise within 1e-5 + 1e-5 |want|.
#[track_caller]
pub fn assert_close(got: &Tensor, want: &Tensor, what: &str) {
    assert_eq!(got.size(), want.size(), "{what}: shape");
    let err = (got.to_kind(Kind::Double) - want.to_kind(Kind::Double)).abs();
    let tol = want.to_kind(Kind::Double).abs() * 1e-5 + 1e-5;
    let bad = (err - tol).max().double_value(&[]);
    assert!(bad <= 0.0, "{what}: got {got:?}, want {want:?}");
}

/// Within 1e-5 + 1e-5 |want|.
#[track_caller]
pub fn assert_close_scalar(got: f64, want: f64, what: &str) {
    assert!(
        (got - want).abs() <= 1e-5 + 1e-5 * want.abs(),
        "{what}: got {got}, want {want}"
    );
}
/// Named parameters from a golden `{name: {shape, data}}` object.
pub fn named_arrays(v: &Value) -> Vec<NamedArray> {
    v.as_object()
        .unwrap()
        .iter()
        .map(|(name, t)| NamedArray {
            name: name.clone(),
            shape: t["shape"]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_i64().unwrap())
                .collect(),
            data: t["data"]
                .as_array()
                .unwrap()
                .iter()
                .map(|x| x.as_f64().unwrap() as f32)
                .collect(),
        })
        .collect()
}

/// A learner statistic against a golden list, as `assert_close`.
#[track_caller]
pub fn assert_close_vec(got: &[f32], want: &Value, what: &str) {
    assert_close(&Tensor::from_slice(got), &vector(want), what);
}
