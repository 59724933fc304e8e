//! Errors. User data never panics: every problem becomes an [`Error`] that says
//! where (file, line, column) and what.

use std::path::PathBuf;

/// Where in a CSV file a problem sits. Lines count from 1 and include the header.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Location {
    pub file: PathBuf,
    pub line: Option<usize>,
    pub column: Option<String>,
}

impl std::fmt::Display for Location {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{}", self.file.display())?;
        if let Some(line) = self.line {
            write!(f, ", line {line}")?;
        }
        if let Some(column) = &self.column {
            write!(f, ", column `{column}`")?;
        }
        Ok(())
    }
}

#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error("{path}: {source}")]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// Bad or inconsistent input data, located precisely.
    #[error("{location}: {message}")]
    Data { location: Location, message: String },
    /// Input that is well-formed but cannot be used as asked (bad flag values, a
    /// method that needs data the scene lacks).
    #[error("{0}")]
    Invalid(String),
    /// The constraints admit no force field (e.g. μ too small for the stresses).
    #[error("infeasible: {0}")]
    Infeasible(String),
    /// The solver failed; the message carries its diagnostics.
    #[error("solver failed: {0}")]
    Solver(String),
}

impl Error {
    pub fn data(
        file: impl Into<PathBuf>,
        line: Option<usize>,
        column: Option<&str>,
        message: impl Into<String>,
    ) -> Self {
        Error::Data {
            location: Location {
                file: file.into(),
                line,
                column: column.map(str::to_owned),
            },
            message: message.into(),
        }
    }

    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
