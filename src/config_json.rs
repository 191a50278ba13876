//! Partial JSON configurations merged over a configuration's defaults: what `--config FILE` of the
//! commands and the `config=` argument of the Python package read.
//!
//! A partial configuration such as `{"register": {"voxel": 0.03}}` in a calibrate configuration changes that
//! one field and keeps the defaults for the rest of `register` (which serde's field defaults alone would
//! replace by `RegisterConfig::default()`).

use crate::error::{Error, Result};
use serde::de::DeserializeOwned;
use serde::Serialize;

/// `T` from a partial JSON configuration (the text of a JSON object) merged over the serialised
/// `T::default()` ([`merge_json`]). Errors ([`Error::InvalidInput`]) carry serde's message, which names an
/// unknown key.
pub fn config_from_json<T: DeserializeOwned + Serialize + Default>(text: &str) -> Result<T> {
    let patch: serde_json::Value =
        serde_json::from_str(text).map_err(|e| Error::InvalidInput(e.to_string()))?;
    config_from_value(patch)
}

/// As [`config_from_json`], from a parsed JSON value (which must be an object).
pub fn config_from_value<T: DeserializeOwned + Serialize + Default>(
    patch: serde_json::Value,
) -> Result<T> {
    if !patch.is_object() {
        return Err(Error::InvalidInput(
            "expected a JSON object of configuration fields".into(),
        ));
    }
    let mut merged =
        serde_json::to_value(T::default()).map_err(|e| Error::InvalidInput(e.to_string()))?;
    merge_json(&mut merged, patch);
    serde_json::from_value(merged).map_err(|e| Error::InvalidInput(e.to_string()))
}

/// Deep merge: every key of `patch` replaces the one of `base`, except that objects present in both are
/// merged key by key. A one-key object over a different one-key object (an enum changing variant, e.g.
/// `{"fixed": 0.5}` over `{"auto": {...}}`) replaces it.
pub fn merge_json(base: &mut serde_json::Value, patch: serde_json::Value) {
    use serde_json::Value;
    match (base, patch) {
        (Value::Object(b), Value::Object(p)) => {
            let other_variant = b.len() == 1 && p.len() == 1 && p.keys().ne(b.keys());
            if other_variant {
                *b = p;
                return;
            }
            for (k, v) in p {
                match b.get_mut(&k) {
                    Some(slot) => merge_json(slot, v),
                    None => {
                        b.insert(k, v);
                    }
                }
            }
        }
        (b, p) => *b = p,
    }
}
