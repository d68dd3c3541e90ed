//! Reading a configuration: TOML files (with `base` chains), built-in text and `--set`
//! overrides.

use std::path::Path;

use super::Config;
use crate::error::{CoreError, Result, read_file};

/// Parses a `--set` value: TOML syntax when it parses (numbers, booleans, arrays, quoted
/// strings), otherwise a bare string.
fn parse_value(text: &str) -> toml::Value {
    let doc = format!("v = {text}");
    match doc.parse::<toml::Table>() {
        Ok(mut t) => t.remove("v").unwrap_or(toml::Value::String(text.into())),
        Err(_) => toml::Value::String(text.into()),
    }
}

/// Lays `over` onto `base`: tables merge key by key, everything else replaces.
fn merge(base: &mut toml::Table, over: toml::Table) {
    for (k, v) in over {
        match (base.get_mut(&k), v) {
            (Some(toml::Value::Table(b)), toml::Value::Table(o)) => merge(b, o),
            (_, v) => {
                base.insert(k, v);
            }
        }
    }
}

/// Reads a TOML file, following `base = "..."` (relative to the file, at most 8 deep).
fn load_table(path: &Path, depth: usize) -> Result<toml::Table> {
    if depth > 8 {
        return Err(CoreError::format(path, "`base` chain deeper than 8 (a cycle?)"));
    }
    let bytes = read_file(path)?;
    let text = String::from_utf8(bytes).map_err(|_| CoreError::format(path, "not UTF-8 text"))?;
    let mut table: toml::Table = text.parse().map_err(|e| CoreError::format(path, format!("invalid TOML: {e}")))?;
    match table.remove("base") {
        None => Ok(table),
        Some(toml::Value::String(b)) => {
            let base_path = path.parent().unwrap_or(Path::new(".")).join(b);
            let mut base = load_table(&base_path, depth + 1)?;
            merge(&mut base, table);
            Ok(base)
        }
        Some(_) => Err(CoreError::format(path, "`base` must be a string (a path relative to this file)")),
    }
}

impl Config {
    /// Reads a TOML file and applies `key=value` overrides. A file may start from another one
    /// with a top-level `base = "other.toml"` (relative to the file; chains allowed): its keys
    /// are laid over the base's, section by section.
    pub fn load(path: Option<&Path>, overrides: &[String]) -> Result<Self> {
        match path {
            Some(p) => {
                let table = load_table(p, 0)?;
                Self::from_table(table, &p.display().to_string(), overrides)
            }
            None => Self::from_toml_str("", "<defaults>", overrides),
        }
    }

    /// Parses TOML text (`name` for messages) and applies `key=value` overrides (`base` is not
    /// followed: there is no file to resolve it against).
    pub fn from_toml_str(text: &str, name: &str, overrides: &[String]) -> Result<Self> {
        let table: toml::Table =
            text.parse().map_err(|e| CoreError::Format { path: name.into(), problem: format!("invalid TOML: {e}") })?;
        Self::from_table(table, name, overrides)
    }

    fn from_table(mut table: toml::Table, name: &str, overrides: &[String]) -> Result<Self> {
        let name = name.to_string();
        for o in overrides {
            let (key, value) = o
                .split_once('=')
                .ok_or_else(|| CoreError::invalid(format!("override `{o}` is not of the form section.key=value")))?;
            let parts: Vec<&str> = key.trim().split('.').collect();
            let mut t = &mut table;
            for p in &parts[..parts.len() - 1] {
                t = t
                    .entry(p.to_string())
                    .or_insert_with(|| toml::Value::Table(toml::Table::new()))
                    .as_table_mut()
                    .ok_or_else(|| CoreError::invalid(format!("override `{o}`: `{p}` is not a section")))?;
            }
            t.insert(parts[parts.len() - 1].to_string(), parse_value(value.trim()));
        }
        let cfg: Config = toml::Value::Table(table).try_into().map_err(|e: toml::de::Error| {
            let problem = e.to_string();
            // A bad value or an unknown key an override set is the override's fault, not the file's.
            let by_override = overrides.iter().rev().find(|o| {
                o.split_once('=').is_some_and(|(key, _)| {
                    let key = key.trim();
                    let last = key.rsplit('.').next().unwrap_or(key);
                    problem.contains(&format!("in `{key}`")) || problem.contains(&format!("unknown field `{last}`"))
                })
            });
            match by_override {
                Some(o) => CoreError::invalid(format!("override `{o}`: {}", problem.trim_end())),
                None => CoreError::Format { path: name.into(), problem },
            }
        })?;
        cfg.validate()?;
        Ok(cfg)
    }
}
