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

/// A plot window `x_min,x_max,y_min,y_max`: four numbers (the figure code checks that they
/// make a window).
pub fn parse_window(text: &str) -> Result<[f64; 4], String> {
    let numbers: Vec<f64> = text
        .split(',')
        .map(|v| v.trim().parse::<f64>().map_err(|e| format!("`{v}`: {e}")))
        .collect::<Result<_, _>>()?;
    numbers
        .try_into()
        .map_err(|n: Vec<f64>| format!("4 numbers x_min,x_max,y_min,y_max, got {}", n.len()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn windows_are_four_numbers_negative_ones_included() {
        assert_eq!(parse_window("-1.5,1,-2,-1"), Ok([-1.5, 1.0, -2.0, -1.0]));
        assert!(parse_window("0,1,0").is_err());
        assert!(parse_window("0,1,0,1,2").is_err());
        assert!(parse_window("0,1,0,x").is_err());
    }

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
    fn contexts_are_separated_by_semicolons_and_their_entries_by_commas() {
        assert_eq!(
            parse_contexts("0; 0.5,1"),
            Ok(vec![vec![0.0], vec![0.5, 1.0]])
        );
        assert!(parse_contexts("0;x").unwrap_err().contains("context `x`"));
    }
}
