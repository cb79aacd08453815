//! JSON read strictly, for calibration files: a duplicated key is an error (serde_json alone
//! keeps the last value), and every error names the field it was found in
//! (`value0.intrinsics[0].intrinsics.fx`) as well as the line and column.

use crate::geometry::rig::quoted;
use serde::de::{self, DeserializeSeed, MapAccess, SeqAccess, Visitor};
use serde_json::{Map, Number, Value};
use std::cell::RefCell;
use std::fmt;

/// One step of the path to a value: an object's key or an array's index.
enum Step {
    Key(String),
    Index(usize),
}

/// A JSON text that could not be read: where (`path`, empty at the top) and what.
#[derive(Debug)]
pub(crate) struct JsonError {
    pub path: String,
    pub message: String,
}

impl fmt::Display for JsonError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.path.is_empty() {
            write!(f, "{}", self.message)
        } else {
            write!(f, "field '{}': {}", self.path, self.message)
        }
    }
}

/// `text` as a JSON value; refuses duplicated keys, naming the key and its path.
pub(crate) fn parse_strict(text: &str) -> Result<Value, JsonError> {
    let path = RefCell::new(Vec::new());
    let mut de = serde_json::Deserializer::from_str(text);
    let value = Tree { path: &path }
        .deserialize(&mut de)
        .and_then(|v| de.end().map(|()| v));
    value.map_err(|e| JsonError {
        path: render(&path.borrow()),
        message: format!("{e}{}", hint(text, &e)),
    })
}

/// `value0.intrinsics[0].intrinsics.fx`; keys that are not plain words are quoted.
fn render(path: &[Step]) -> String {
    let mut out = String::new();
    for step in path {
        match step {
            Step::Index(i) => out.push_str(&format!("[{i}]")),
            Step::Key(k) => {
                if !out.is_empty() {
                    out.push('.');
                }
                let plain = !k.is_empty()
                    && k.len() <= 64
                    && k.chars().all(|c| c.is_ascii_alphanumeric() || c == '_');
                out.push_str(&if plain { k.clone() } else { quoted(k) });
            }
        }
    }
    out
}

/// What a bare serde_json message leaves a user to guess.
fn hint(text: &str, e: &serde_json::Error) -> &'static str {
    let msg = e.to_string();
    if msg.starts_with("number out of range") {
        return " (beyond the range of a 64-bit float)";
    }
    let near: String = text
        .lines()
        .nth(e.line().saturating_sub(1))
        .unwrap_or("")
        .chars()
        .skip(e.column().saturating_sub(2))
        .take(12)
        .collect();
    if ["NaN", "nan", "Infinity", "inf"]
        .iter()
        .any(|w| near.contains(w))
    {
        return " (JSON has no NaN or Infinity: every value must be a finite number)";
    }
    ""
}

/// Builds a [`Value`], keeping in `path` the way to the value being read: on an error, the
/// path stays at the value that failed.
struct Tree<'a> {
    path: &'a RefCell<Vec<Step>>,
}

impl<'de> DeserializeSeed<'de> for Tree<'_> {
    type Value = Value;

    fn deserialize<D: de::Deserializer<'de>>(self, d: D) -> Result<Value, D::Error> {
        d.deserialize_any(self)
    }
}

impl<'de> Visitor<'de> for Tree<'_> {
    type Value = Value;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a JSON value")
    }

    fn visit_bool<E>(self, v: bool) -> Result<Value, E> {
        Ok(Value::Bool(v))
    }

    fn visit_i64<E>(self, v: i64) -> Result<Value, E> {
        Ok(Value::Number(v.into()))
    }

    fn visit_u64<E>(self, v: u64) -> Result<Value, E> {
        Ok(Value::Number(v.into()))
    }

    fn visit_f64<E: de::Error>(self, v: f64) -> Result<Value, E> {
        Number::from_f64(v)
            .map(Value::Number)
            .ok_or_else(|| E::custom(format!("{v} is not a finite number")))
    }

    fn visit_str<E>(self, v: &str) -> Result<Value, E> {
        Ok(Value::String(v.to_owned()))
    }

    fn visit_string<E>(self, v: String) -> Result<Value, E> {
        Ok(Value::String(v))
    }

    fn visit_unit<E>(self) -> Result<Value, E> {
        Ok(Value::Null)
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<Value, A::Error> {
        let mut out = Vec::new();
        loop {
            self.path.borrow_mut().push(Step::Index(out.len()));
            let next = seq.next_element_seed(Tree { path: self.path })?;
            self.path.borrow_mut().pop();
            match next {
                Some(v) => out.push(v),
                None => return Ok(Value::Array(out)),
            }
        }
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<Value, A::Error> {
        let mut out = Map::new();
        while let Some(key) = map.next_key::<String>()? {
            let duplicate = out.contains_key(&key);
            self.path.borrow_mut().push(Step::Key(key.clone()));
            if duplicate {
                return Err(de::Error::custom(format!(
                    "duplicate key {} (each key may appear once)",
                    quoted(&key)
                )));
            }
            let v = map.next_value_seed(Tree { path: self.path })?;
            self.path.borrow_mut().pop();
            out.insert(key, v);
        }
        Ok(Value::Object(out))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn err(text: &str) -> String {
        parse_strict(text).unwrap_err().to_string()
    }

    #[test]
    fn duplicates_and_bad_numbers_name_the_field() {
        let v = parse_strict(r#"{"a": [1, {"b": 2.5}], "c": null}"#).unwrap();
        assert_eq!(v["a"][1]["b"], 2.5);
        let e = err(r#"{"a": [1, {"b": 2.5, "b": 3}]}"#);
        assert!(
            e.starts_with("field 'a[1].b': duplicate key \"b\"") && e.contains("line 1"),
            "{e}"
        );
        let e = err(r#"{"value0": {"x": 1}, "value0": {}}"#);
        assert!(e.starts_with("field 'value0': duplicate key"), "{e}");
        let e = err("{\"a\": {\"fx\": NaN}}");
        assert!(
            e.starts_with("field 'a.fx': expected value") && e.contains("no NaN"),
            "{e}"
        );
        let e = err("{\"a\": {\"fx\": -Infinity}}");
        assert!(
            e.starts_with("field 'a.fx'") && e.contains("no NaN or Infinity"),
            "{e}"
        );
        let e = err("{\"a\": [1e400]}");
        assert!(
            e.starts_with("field 'a[0]': number out of range") && e.contains("64-bit"),
            "{e}"
        );
        let e = err("{\"a\": 1} x");
        assert!(e.starts_with("trailing characters"), "{e}");
    }
}
