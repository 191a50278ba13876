#![cfg(not(feature = "vision"))]
//! Without the `vision` feature `depthcal match` says that it needs it and how to build it.

mod common;

#[test]
fn match_says_it_needs_the_vision_feature() {
    let (code, _, err) = common::depthcal(&["match", "a.png", "b.png", "--json"]);
    assert_eq!(code, 1);
    assert!(
        err.contains("depthcal match") && err.contains("without the `vision` feature"),
        "{err}"
    );
    assert!(err.contains("--features vision"), "{err}");
}
