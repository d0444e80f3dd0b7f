//! Value parsers of the command line's arguments, shared by the commands.

/// `NAME=VALUE` as its two parts.
pub fn parse_key_value(text: &str) -> Result<(String, String), String> {
    let (key, value) = text
        .split_once('=')
        .ok_or_else(|| format!("`{text}` is not NAME=VALUE"))?;
    Ok((key.to_string(), value.to_string()))
}

/// `[NAME=]DIR`: a checkpoint directory, optionally named.
pub fn parse_named_dir(text: &str) -> Result<(Option<String>, std::path::PathBuf), String> {
    Ok(match text.split_once('=') {
        Some((name, dir)) => (Some(name.to_owned()), dir.into()),
        None => (None, text.into()),
    })
}

/// `NAME=VALUE` with a number for VALUE.
pub fn parse_number_pair(text: &str) -> Result<(String, f64), String> {
    let (key, value) = parse_key_value(text)?;
    let number = value
        .parse()
        .map_err(|_| format!("`{value}` in `{text}` is not a number"))?;
    Ok((key, number))
}

/// `NAME` (held at 0) or `NAME=POSITION`: a joint to lock.
pub fn parse_locked_joint(text: &str) -> Result<ciflow_engine::robot::LockedJoint, String> {
    let (name, position) = match text.split_once('=') {
        Some(_) => parse_number_pair(text)?,
        None => (text.to_owned(), 0.0),
    };
    if name.is_empty() {
        return Err(format!("`{text}` names no joint"));
    }
    Ok(ciflow_engine::robot::LockedJoint { name, position })
}

/// `;`-separated contexts, each comma-separated.
pub fn parse_contexts(text: &str) -> Result<Vec<Vec<f64>>, String> {
    text.split(';')
        .map(|c| {
            c.split(',')
                .map(|v| v.trim().parse::<f64>())
                .collect::<Result<_, _>>()
                .map_err(|e| format!("context `{c}`: {e}"))
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pairs_split_at_the_first_equals_sign() {
        assert_eq!(
            parse_key_value("shape=a=b"),
            Ok(("shape".into(), "a=b".into()))
        );
        assert!(parse_key_value("shape").is_err());
        assert_eq!(
            parse_number_pair("obstacles=2"),
            Ok(("obstacles".into(), 2.0))
        );
        assert!(parse_number_pair("obstacles=two").is_err());
    }

    #[test]
    fn a_locked_joint_is_held_at_zero_unless_given_a_position() {
        let locked = |name: &str, position| ciflow_engine::robot::LockedJoint {
            name: name.into(),
            position,
        };
        assert_eq!(parse_locked_joint("finger"), Ok(locked("finger", 0.0)));
        assert_eq!(
            parse_locked_joint("finger=0.02"),
            Ok(locked("finger", 0.02))
        );
        assert!(parse_locked_joint("finger=wide").is_err());
        assert!(parse_locked_joint("=0.1").is_err());
    }

    #[test]
    fn contexts_are_separated_by_semicolons_and_their_entries_by_commas() {
        assert_eq!(
            parse_contexts("0; 0.5,1"),
            Ok(vec![vec![0.0], vec![0.5, 1.0]])
        );
        assert!(parse_contexts("0;x").unwrap_err().contains("context `x`"));
    }
}
