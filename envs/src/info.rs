//! [`Info`]: the named reals a step or a reset reports beside its observation, as in
//! Gymnasium's `info` dict.
//!
//! A task reports a handful of values at every step (a planar task four), millions of
//! times a second when an engine steps thousands of environments. A sorted map paid for
//! its keys at every step: it compared them to sort them, allocated a node for them and
//! freed it again (550 of an obstacle step's 6 200 instructions).
//! `Info` keeps up to [`INLINE`] entries inside the value, in the order they were set, so
//! building and dropping one neither allocates nor orders anything; keys stay unique.
//! Equality ignores the order, as a dict's does.

use std::borrow::Cow;
use std::fmt;

use serde::de::{MapAccess, Visitor};
use serde::ser::SerializeMap;
use serde::{Deserialize, Deserializer, Serialize, Serializer};
use smallvec::SmallVec;

/// Entries held without allocating; more spill to the heap (the Panda's pouring reports
/// ten).
pub const INLINE: usize = 4;

/// A key of an [`Info`]: a task's `'static` name, or one read off the wire.
pub type InfoKey = Cow<'static, str>;

/// Extra per-step or per-reset values, as in Gymnasium's `info` dict. Numbers only, so
/// that every wire format carries them; iterated in the order the keys were first set.
#[derive(Clone, Default)]
pub struct Info(SmallVec<[(InfoKey, f64); INLINE]>);

impl Info {
    pub fn new() -> Self {
        Self::default()
    }

    /// Sets `key` to `value`; returns the value it replaces, if the key was there.
    pub fn insert(&mut self, key: InfoKey, value: f64) -> Option<f64> {
        match self.0.iter_mut().find(|(k, _)| *k == key) {
            Some((_, old)) => Some(std::mem::replace(old, value)),
            None => {
                self.0.push((key, value));
                None
            }
        }
    }

    /// Removes every entry, keeping the memory (an environment refills the same `Info`
    /// at every step).
    pub fn clear(&mut self) {
        self.0.clear();
    }

    pub fn get(&self, key: &str) -> Option<&f64> {
        self.0.iter().find(|(k, _)| k == key).map(|(_, v)| v)
    }

    pub fn contains_key(&self, key: &str) -> bool {
        self.get(key).is_some()
    }

    pub fn len(&self) -> usize {
        self.0.len()
    }

    pub fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// The entries, in the order their keys were first set.
    pub fn iter(&self) -> Iter<'_> {
        Iter(self.0.iter())
    }
}

/// The value of `key`, as a map's `info["key"]`.
///
/// # Panics
/// If the key is not there (use [`Info::get`] when it may not be).
impl std::ops::Index<&str> for Info {
    type Output = f64;

    fn index(&self, key: &str) -> &f64 {
        self.get(key)
            .unwrap_or_else(|| panic!("no info key `{key}`"))
    }
}

impl PartialEq for Info {
    fn eq(&self, other: &Self) -> bool {
        self.len() == other.len() && self.iter().all(|(k, v)| other.get(k) == Some(v))
    }
}

impl fmt::Debug for Info {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.debug_map().entries(self.iter()).finish()
    }
}

impl<const N: usize> From<[(InfoKey, f64); N]> for Info {
    fn from(entries: [(InfoKey, f64); N]) -> Self {
        entries.into_iter().collect()
    }
}

impl FromIterator<(InfoKey, f64)> for Info {
    /// A repeated key keeps its first place and its last value, as `insert` would.
    fn from_iter<I: IntoIterator<Item = (InfoKey, f64)>>(entries: I) -> Self {
        let mut info = Self::new();
        info.extend(entries);
        info
    }
}

impl Extend<(InfoKey, f64)> for Info {
    /// Inserts each entry in turn, as [`Info::insert`].
    fn extend<I: IntoIterator<Item = (InfoKey, f64)>>(&mut self, entries: I) {
        for (key, value) in entries {
            self.insert(key, value);
        }
    }
}

/// The entries of an [`Info`], in the order their keys were first set. A type of its own
/// rather than a `map` over the slice's iterator through a function pointer, which an
/// engine called indirectly for every value of every environment it stepped.
pub struct Iter<'a>(std::slice::Iter<'a, (InfoKey, f64)>);

impl<'a> Iterator for Iter<'a> {
    type Item = (&'a InfoKey, &'a f64);

    #[inline]
    fn next(&mut self) -> Option<Self::Item> {
        self.0.next().map(|(key, value)| (key, value))
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        self.0.size_hint()
    }
}

impl ExactSizeIterator for Iter<'_> {}

impl<'a> IntoIterator for &'a Info {
    type Item = (&'a InfoKey, &'a f64);
    type IntoIter = Iter<'a>;

    fn into_iter(self) -> Iter<'a> {
        self.iter()
    }
}

impl IntoIterator for Info {
    type Item = (InfoKey, f64);
    type IntoIter = smallvec::IntoIter<[(InfoKey, f64); INLINE]>;

    fn into_iter(self) -> Self::IntoIter {
        self.0.into_iter()
    }
}

/// A map from strings to numbers, as the `info` of every protocol message.
impl Serialize for Info {
    fn serialize<S: Serializer>(&self, serializer: S) -> Result<S::Ok, S::Error> {
        let mut map = serializer.serialize_map(Some(self.len()))?;
        for (key, value) in self {
            map.serialize_entry(key.as_ref(), value)?;
        }
        map.end()
    }
}

impl<'de> Deserialize<'de> for Info {
    fn deserialize<D: Deserializer<'de>>(deserializer: D) -> Result<Self, D::Error> {
        deserializer.deserialize_map(InfoVisitor)
    }
}

struct InfoVisitor;

impl<'de> Visitor<'de> for InfoVisitor {
    type Value = Info;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a map from strings to numbers")
    }

    fn visit_map<A: MapAccess<'de>>(self, mut entries: A) -> Result<Info, A::Error> {
        let mut info = Info::new();
        while let Some((key, value)) = entries.next_entry::<String, f64>()? {
            info.insert(key.into(), value);
        }
        Ok(info)
    }
}

#[cfg(test)]
mod tests {
    use std::collections::BTreeMap;

    use super::*;

    fn entries(info: &Info) -> Vec<(String, f64)> {
        info.iter().map(|(k, v)| (k.to_string(), *v)).collect()
    }

    /// The map behaviour of the `BTreeMap` it replaced, entry by entry, over a sequence
    /// of inserts that repeats keys and spills past the inline entries.
    #[test]
    fn behaves_as_a_map() {
        let keys = ["b", "a", "time", "b", "c", "d", "a", "e", "f"];
        let (mut info, mut reference) = (Info::new(), BTreeMap::new());
        for (i, key) in keys.into_iter().enumerate() {
            let value = i as f64;
            assert_eq!(
                info.insert(key.into(), value),
                reference.insert(key, value),
                "{key}"
            );
            assert_eq!(info.len(), reference.len());
            for probe in keys.iter().chain(&["absent"]) {
                assert_eq!(info.get(probe), reference.get(probe), "{probe}");
                assert_eq!(info.contains_key(probe), reference.contains_key(probe));
            }
        }
        // First-set order, last value.
        let order: Vec<&str> = info.iter().map(|(k, _)| k.as_ref()).collect();
        assert_eq!(order, ["b", "a", "time", "c", "d", "e", "f"]);
        assert_eq!(info["a"], 6.0);
    }

    #[test]
    #[should_panic(expected = "no info key `absent`")]
    fn indexing_a_missing_key_names_it() {
        let _ = Info::from([("a".into(), 1.0)])["absent"];
    }

    #[test]
    fn equality_ignores_order_but_not_values_or_keys() {
        let info = Info::from([("a".into(), 1.0), ("b".into(), 2.0)]);
        assert_eq!(info, Info::from([("b".into(), 2.0), ("a".into(), 1.0)]));
        assert_ne!(info, Info::from([("a".into(), 1.0), ("b".into(), 3.0)]));
        assert_ne!(info, Info::from([("a".into(), 1.0), ("c".into(), 2.0)]));
        assert_ne!(info, Info::from([("a".into(), 1.0)]));
        assert_ne!(Info::from([("a".into(), 1.0)]), info);
    }

    /// The wire form is a plain map: what a `BTreeMap` of the same entries writes reads
    /// back as the same `Info`, and an `Info` reads back as that map.
    #[test]
    fn travels_as_a_map() {
        let info = Info::from([
            ("time".into(), 0.25),
            ("is_success".into(), 1.0),
            ("x".into(), -3.5),
        ]);
        let map: BTreeMap<String, f64> = entries(&info).into_iter().collect();
        let written = serde_json::to_string(&info).unwrap();
        assert_eq!(
            serde_json::from_str::<BTreeMap<String, f64>>(&written).unwrap(),
            map
        );
        let read: Info = serde_json::from_str(&serde_json::to_string(&map).unwrap()).unwrap();
        assert_eq!(read, info);
        assert!(serde_json::from_str::<Info>(r#"{"a": "text"}"#).is_err());
    }
}
