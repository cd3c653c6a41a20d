//! The weights file's record of how its weights were made (command, steps, seed, time,
//! validation), and what that record carries over when a run starts from other weights
//! (`--init`) or continues an interrupted one (`--resume`).

use serde_json::{Map, Value};

/// What a new run inherits from the weights it starts from.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Lineage(Map<String, Value>);

impl Lineage {
    /// A run from fresh weights inherits nothing.
    pub fn fresh() -> Self {
        Self::default()
    }

    /// A run started from weights with `provenance` keeps their record under `init_from`.
    pub fn init_from(provenance: Value) -> Self {
        let mut m = Map::new();
        m.insert("init_from".into(), provenance);
        Self(m)
    }

    /// A resumed run keeps the command that started it, its `init_from`, and the list of
    /// resumptions, to which this one (at `at_step`) is added.
    pub fn resumed(provenance: Value, at_step: usize) -> Self {
        let mut m = Map::new();
        let Value::Object(mut p) = provenance else {
            return Self(m);
        };
        let mut resumed = match p.remove("resumed") {
            Some(Value::Array(v)) => v,
            _ => vec![],
        };
        resumed.push(serde_json::json!({ "at_step": at_step }));
        p.insert("resumed".into(), resumed.into());
        for key in ["command", "init_from", "resumed"] {
            if let Some(v) = p.remove(key) {
                m.insert(key.into(), v);
            }
        }
        Self(m)
    }

    /// The record of this run (`record`, made by the caller, with its own `command`) with
    /// the inheritance on top: a resumed run keeps the command that started it, and this
    /// invocation's command goes into the last resumption.
    pub fn apply(&self, mut record: Value, command: &str) -> Value {
        for (k, v) in &self.0 {
            if k == "resumed" {
                let mut v = v.clone();
                if let Some(last) = v.as_array_mut().and_then(|r| r.last_mut()) {
                    last["command"] = command.into();
                }
                record[k] = v;
            } else {
                record[k] = v.clone();
            }
        }
        record
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    #[test]
    fn resuming_twice_keeps_the_first_command_and_lists_both_resumptions() {
        let first = Lineage::fresh().apply(json!({"command": "a", "steps": 10}), "a");
        assert_eq!(first["command"], "a");
        let second = Lineage::resumed(first, 10).apply(json!({"command": "b", "steps": 20}), "b");
        assert_eq!(second["command"], "a");
        assert_eq!(second["steps"], 20);
        assert_eq!(second["resumed"], json!([{"at_step": 10, "command": "b"}]));
        let third = Lineage::resumed(second, 20).apply(json!({"command": "c"}), "c");
        assert_eq!(third["command"], "a");
        assert_eq!(
            third["resumed"],
            json!([{"at_step": 10, "command": "b"}, {"at_step": 20, "command": "c"}])
        );
    }

    #[test]
    fn init_keeps_the_source_record_whole() {
        let src = json!({"command": "old", "val_psnr": 30.0});
        let p = Lineage::init_from(src.clone()).apply(json!({"command": "new"}), "new");
        assert_eq!(p["command"], "new");
        assert_eq!(p["init_from"], src);
        assert!(p.get("resumed").is_none());
    }
}
