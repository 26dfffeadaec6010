//! `--set a.b.c=value` on the parsed TOML table.
use toml::{Table, Value};

/// Apply one `key=value` override. The value is read as a TOML value (`1e-6`, `true`,
/// `"adiabatic"`, `[1.0, 2.0]`); a bare word that is not valid TOML is taken as a string.
/// Numeric path segments index arrays (`dust.fractions.0.t_stop`). An empty value removes
/// the key (`--set time.cfl= --set time.dt=0.01` switches to a fixed step).
pub fn apply_override(table: &mut Table, ov: &str) -> Result<(), (Option<String>, String)> {
    let (key, raw) = ov.split_once('=').ok_or_else(|| {
        (
            None,
            format!("--set `{ov}`: expected key=value (e.g. --set dust.fractions.0.t_stop=1e-6)"),
        )
    })?;
    let key = key.trim();
    let raw = raw.trim();
    if key.is_empty() {
        return Err((None, format!("--set `{ov}`: empty key")));
    }
    let value = if raw.is_empty() {
        None
    } else {
        Some(match format!("v = {raw}").parse::<Table>() {
            Ok(mut t) => t.remove("v").unwrap_or(Value::String(raw.to_string())),
            // A bare word is a string (`--set gas.eos=adiabatic`); what starts like a number,
            // an array, a table or a quoted string but does not parse is a typo, not a string.
            Err(e)
                if raw.starts_with(['[', '{', '"', '\'', '+', '-', '.'])
                    || raw.starts_with(|c: char| c.is_ascii_digit()) =>
            {
                let why = e.message().trim().replace('\n', "; ");
                return Err((
                    Some(key.to_string()),
                    format!("--set: `{raw}` is not a valid TOML value ({})", why.trim()),
                ));
            }
            Err(_) => Value::String(raw.to_string()),
        })
    };
    let parts: Vec<&str> = key.split('.').collect();
    let mut root = Value::Table(std::mem::take(table));
    let res = set_path(&mut root, &parts, value);
    if let Value::Table(t) = root {
        *table = t;
    }
    res.map_err(|msg| (Some(key.to_string()), format!("--set: {msg}")))
}

fn set_path(cur: &mut Value, parts: &[&str], value: Option<Value>) -> Result<(), String> {
    let Some((part, rest)) = parts.split_first() else {
        if let Some(v) = value {
            *cur = v;
        }
        return Ok(());
    };
    if rest.is_empty() && value.is_none() {
        return match cur {
            Value::Table(t) => t
                .remove(*part)
                .map(|_| ())
                .ok_or_else(|| format!("cannot remove `{part}`: no such key")),
            _ => Err(format!(
                "cannot remove `{part}`: only table keys can be removed"
            )),
        };
    }
    let next = match cur {
        Value::Table(t) => t
            .entry(part.to_string())
            .or_insert_with(|| Value::Table(Table::new())),
        Value::Array(a) => {
            let idx: usize = part
                .parse()
                .map_err(|_| format!("`{part}` must be an array index"))?;
            let len = a.len();
            a.get_mut(idx)
                .ok_or_else(|| format!("index {idx} out of range (array has {len} entries)"))?
        }
        _ => return Err(format!("`{part}` is inside a value that is not a table")),
    };
    set_path(next, rest, value)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sets_nested_and_indexed_values() {
        let mut t: Table = "[a]\nb = 1\n[[f]]\nx = 1.0\n[[f]]\nx = 2.0\n"
            .parse()
            .unwrap();
        apply_override(&mut t, "a.b=3").unwrap();
        apply_override(&mut t, "f.1.x=1e-6").unwrap();
        apply_override(&mut t, "c.d=adiabatic").unwrap();
        assert_eq!(t["a"]["b"].as_integer(), Some(3));
        assert_eq!(t["f"][1]["x"].as_float(), Some(1e-6));
        assert_eq!(t["c"]["d"].as_str(), Some("adiabatic"));
        apply_override(&mut t, "a.b=").unwrap();
        assert!(t["a"].get("b").is_none());
        assert!(apply_override(&mut t, "a.zz=").is_err());
    }

    #[test]
    fn rejects_bad_index_and_missing_equals() {
        let mut t: Table = "[[f]]\nx = 1.0\n".parse().unwrap();
        let e = apply_override(&mut t, "f.3.x=1").unwrap_err();
        assert_eq!(e.0.as_deref(), Some("f.3.x"));
        assert!(apply_override(&mut t, "f.0.x").is_err());
    }
}
