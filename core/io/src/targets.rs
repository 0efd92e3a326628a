//! A targets file: the known centres of calibration spheres, as `[[target]]` tables with an
//! `id` and a `position = [x, y, z]` in metres. Which frame the positions are in depends on
//! what is calibrated (the design frame for the robot base, the robot base frame for the
//! scanner on the flange); the file does not say, the caller does.

use std::path::{Path, PathBuf};

use serde::Deserialize;

use crate::IoError;

/// One sphere target with its known centre.
#[derive(Debug, Clone, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Target {
    /// The target's name, as warnings and `--exclude` give it.
    pub id: String,
    /// The sphere's centre, metres.
    pub position: [f64; 3],
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct TargetsFile {
    target: Vec<Target>,
}

/// Why a targets file gives no targets to use.
#[derive(Debug, thiserror::Error)]
pub enum TargetsError {
    /// The file cannot be read, or is not a targets file.
    #[error(transparent)]
    File(#[from] IoError),
    /// A target to leave out is not in the file (a typo would otherwise keep it in).
    #[error("--exclude {id:?}: no such target in {}", path.display())]
    UnknownExclude {
        /// The id asked to be left out.
        id: String,
        /// The targets file.
        path: PathBuf,
    },
    /// Nothing is left once the excluded targets are out.
    #[error("{} lists no target to use", path.display())]
    Empty {
        /// The targets file.
        path: PathBuf,
    },
}

/// The targets of the file at `path` but those whose id is in `exclude`, in file order.
pub fn load(path: &Path, exclude: &[String]) -> Result<Vec<Target>, TargetsError> {
    IoError::require_file(path, "targets")?;
    let text = std::fs::read_to_string(path).map_err(|source| IoError::Open {
        path: path.to_path_buf(),
        source,
    })?;
    let file: TargetsFile = toml::from_str(&text).map_err(|e| IoError::Malformed {
        path: path.to_path_buf(),
        format: "a targets file",
        what: format!("{e}\nexpected [[target]] tables with id and position = [x, y, z] in metres"),
    })?;
    if let Some(id) = exclude
        .iter()
        .find(|x| !file.target.iter().any(|t| &t.id == *x))
    {
        return Err(TargetsError::UnknownExclude {
            id: id.clone(),
            path: path.to_path_buf(),
        });
    }
    let targets: Vec<Target> = file
        .target
        .into_iter()
        .filter(|t| !exclude.contains(&t.id))
        .collect();
    if targets.is_empty() {
        return Err(TargetsError::Empty {
            path: path.to_path_buf(),
        });
    }
    Ok(targets)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(text: &str) -> tempfile::NamedTempFile {
        let f = tempfile::NamedTempFile::new().unwrap();
        std::fs::write(f.path(), text).unwrap();
        f
    }

    const TWO: &str = "[[target]]\nid = \"A\"\nposition = [1.0, 2.0, 3.0]\n\
                       [[target]]\nid = \"B\"\nposition = [0.5, 0, -1]\n";

    #[test]
    fn reads_targets_in_file_order_and_leaves_out_the_excluded() {
        let f = file(TWO);
        let all = load(f.path(), &[]).unwrap();
        assert_eq!(
            all,
            vec![
                Target {
                    id: "A".into(),
                    position: [1.0, 2.0, 3.0]
                },
                Target {
                    id: "B".into(),
                    position: [0.5, 0.0, -1.0]
                }
            ]
        );
        let b = load(f.path(), &["A".into()]).unwrap();
        assert_eq!(b.len(), 1);
        assert_eq!(b[0].id, "B");
    }

    #[test]
    fn says_what_is_wrong() {
        let f = file(TWO);
        let e = load(f.path(), &["C".into()]).unwrap_err();
        assert!(matches!(&e, TargetsError::UnknownExclude { id, .. } if id == "C"));
        let e = load(f.path(), &["A".into(), "B".into()]).unwrap_err();
        assert!(e.to_string().contains("lists no target to use"), "{e}");
        let bad = file("[[target]]\nid = \"A\"\nposition = [1.0, 2.0]\n");
        let e = load(bad.path(), &[]).unwrap_err().to_string();
        assert!(e.contains("expected [[target]] tables"), "{e}");
        let e = load(Path::new("/no/such/targets.toml"), &[]).unwrap_err();
        assert!(
            matches!(e, TargetsError::File(IoError::NotFound { .. })),
            "{e}"
        );
    }
}
