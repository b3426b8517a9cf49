//! Settings files, one road for every binary: a `--config` file holds any
//! subset of a settings struct's JSON (as the run wrote it beside its
//! results), laid over the defaults field by field; flags go over that.

use serde::Serialize;
use serde::de::DeserializeOwned;

/// `over`'s fields laid over `base`'s, objects merged field by field: a
/// settings file need only name what it changes.
fn merge_json(base: &mut serde_json::Value, over: &serde_json::Value) {
    match (base, over) {
        (serde_json::Value::Object(b), serde_json::Value::Object(o)) => {
            for (key, value) in o {
                match b.get_mut(key) {
                    Some(slot) => merge_json(slot, value),
                    None => {
                        b.insert(key.clone(), value.clone());
                    }
                }
            }
        }
        (slot, value) => *slot = value.clone(),
    }
}

/// The JSON of a settings file; an error names the file.
pub fn read(path: &std::path::Path) -> crate::Result<serde_json::Value> {
    let text = crate::atomic::read_text(path)?;
    serde_json::from_str(&text).map_err(|e| crate::DataError::json(path, e))
}

/// `defaults` with `file` laid over them; the message names what serde
/// refused (an unknown field, a value of the wrong type).
pub fn overlay<T: Serialize + DeserializeOwned>(defaults: &T, file: &serde_json::Value) -> Result<T, String> {
    let mut merged = serde_json::to_value(defaults).map_err(|e| e.to_string())?;
    merge_json(&mut merged, file);
    serde_json::from_value(merged).map_err(|e| e.to_string())
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde::Deserialize;

    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Inner {
        a: f64,
        b: u32,
    }

    #[derive(Debug, PartialEq, Serialize, Deserialize)]
    #[serde(deny_unknown_fields)]
    struct Outer {
        inner: Inner,
        name: String,
    }

    #[test]
    fn a_file_changes_only_what_it_names_and_unknown_fields_are_refused() {
        let defaults = Outer { inner: Inner { a: 1.5, b: 2 }, name: "x".into() };
        let over = overlay(&defaults, &serde_json::json!({"inner": {"b": 7}})).unwrap();
        assert_eq!(over, Outer { inner: Inner { a: 1.5, b: 7 }, name: "x".into() });
        let e = overlay(&defaults, &serde_json::json!({"inner": {"c": 1}})).unwrap_err();
        assert!(e.contains("unknown field `c`"), "{e}");
        let e = overlay(&defaults, &serde_json::json!({"name": 3})).unwrap_err();
        assert!(e.contains("invalid type"), "{e}");
    }
}
