//! Construction arguments, as `gymnasium.make(id, **kwargs)` takes them: numbers
//! (`obstacles=2`), and texts for the arguments a task declares textual (the reach task's
//! URDF document). Every wire format carries both: a number is written as a number, a
//! text as a string.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use crate::env::EnvError;

/// One construction argument.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(untagged)]
pub enum Kwarg {
    Number(f64),
    Text(String),
}

/// A task's construction arguments by name.
pub type Kwargs = BTreeMap<String, Kwarg>;

impl From<f64> for Kwarg {
    fn from(number: f64) -> Self {
        Kwarg::Number(number)
    }
}

impl From<&str> for Kwarg {
    fn from(text: &str) -> Self {
        Kwarg::Text(text.to_owned())
    }
}

impl From<String> for Kwarg {
    fn from(text: String) -> Self {
        Kwarg::Text(text)
    }
}

/// A construction argument a task takes as text rather than as a number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct TextArgument {
    pub key: &'static str,
    /// The text is a document (e.g. a URDF) given in full or as the path of a file holding
    /// it, read where the argument is given: the environment's identity (datasets,
    /// checkpoints, the engine's sessions) holds the content, never a machine-local path.
    pub file: bool,
}

/// Texts longer than this are shown by their length (a URDF in a dataset's description).
const SHOWN_TEXT: usize = 40;

impl std::fmt::Display for Kwarg {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Kwarg::Number(number) => write!(f, "{number}"),
            Kwarg::Text(text) if text.len() <= SHOWN_TEXT => write!(f, "{text:?}"),
            Kwarg::Text(text) => write!(f, "<a text of {} bytes>", text.len()),
        }
    }
}

/// Arguments written as JSON values (a checkpoint's `task_kwargs`): numbers and strings.
pub fn from_json(values: &BTreeMap<String, serde_json::Value>) -> Result<Kwargs, EnvError> {
    values
        .iter()
        .map(|(name, value)| {
            let kwarg =
                serde_json::from_value(value.clone()).map_err(|_| EnvError::InvalidOption {
                    name: name.clone(),
                    detail: format!("{value} is neither a number nor a text"),
                })?;
            Ok((name.clone(), kwarg))
        })
        .collect()
}

/// The arguments as JSON values ([`from_json`] reads them back).
pub fn to_json(kwargs: &Kwargs) -> BTreeMap<String, serde_json::Value> {
    kwargs
        .iter()
        .map(|(name, kwarg)| {
            let value = match kwarg {
                Kwarg::Number(number) => serde_json::json!(number),
                Kwarg::Text(text) => serde_json::json!(text),
            };
            (name.clone(), value)
        })
        .collect()
}

/// The number given for `name`, if any; a text there is an error.
pub fn number(kwargs: &Kwargs, name: &str) -> Result<Option<f64>, EnvError> {
    match kwargs.get(name) {
        None => Ok(None),
        Some(Kwarg::Number(number)) => Ok(Some(*number)),
        Some(Kwarg::Text(text)) => Err(EnvError::InvalidOption {
            name: name.into(),
            detail: format!("`{text}` is not a number"),
        }),
    }
}

/// The text given for `name`, if any; a number there is an error.
pub fn text<'a>(kwargs: &'a Kwargs, name: &str) -> Result<Option<&'a str>, EnvError> {
    match kwargs.get(name) {
        None => Ok(None),
        Some(Kwarg::Text(text)) => Ok(Some(text)),
        Some(Kwarg::Number(number)) => Err(EnvError::InvalidOption {
            name: name.into(),
            detail: format!("{number} is a number; a text is needed"),
        }),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_and_texts_keep_their_kind_through_json_and_msgpack() {
        let kwargs = Kwargs::from([
            ("obstacles".into(), Kwarg::from(2.0)),
            ("urdf".into(), Kwarg::from("<robot name=\"r\"/>")),
        ]);
        let json = serde_json::to_string(&kwargs).unwrap();
        assert_eq!(json, r#"{"obstacles":2.0,"urdf":"<robot name=\"r\"/>"}"#);
        assert_eq!(serde_json::from_str::<Kwargs>(&json).unwrap(), kwargs);
        let packed = rmp_serde::to_vec_named(&kwargs).unwrap();
        assert_eq!(rmp_serde::from_slice::<Kwargs>(&packed).unwrap(), kwargs);
        assert_eq!(from_json(&to_json(&kwargs)).unwrap(), kwargs);
        let nested = BTreeMap::from([("bad".to_owned(), serde_json::json!([1]))]);
        assert!(from_json(&nested).is_err());
        // Integers, as Python and JSON often write them, are numbers.
        let integer: Kwargs = serde_json::from_str(r#"{"obstacles": 2}"#).unwrap();
        assert_eq!(number(&integer, "obstacles").unwrap(), Some(2.0));
    }

    #[test]
    fn asking_for_the_other_kind_is_an_error() {
        let kwargs = Kwargs::from([
            ("obstacles".into(), Kwarg::from(2.0)),
            ("urdf".into(), Kwarg::from("<robot/>")),
        ]);
        assert_eq!(number(&kwargs, "missing").unwrap(), None);
        assert_eq!(text(&kwargs, "urdf").unwrap(), Some("<robot/>"));
        assert!(number(&kwargs, "urdf").is_err());
        assert!(text(&kwargs, "obstacles").is_err());
    }
}
