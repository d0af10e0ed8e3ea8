//! What produced a run's results: the crate version, a digest of this build and of every
//! feature program, so that `sweep` resumes only runs this very program wrote.

use std::sync::OnceLock;

use anyhow::{Context, Result};
use serde::{Deserialize, Serialize};

use evitrack::scenario::CheckedScenario;

/// The content of a run folder's `producer.json`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub(crate) struct Producer {
    /// The crate's version.
    evitrack: String,
    /// A digest of the running executable ("unknown" when it cannot be read: never resumed).
    build: String,
    /// Each feature program of the scenario: its command line and digest.
    feature_programs: Vec<(Vec<String>, String)>,
}

/// The digest of the running executable, read once.
fn build_digest() -> &'static str {
    static DIGEST: OnceLock<String> = OnceLock::new();
    DIGEST.get_or_init(|| {
        std::env::current_exe()
            .and_then(|exe| evitrack::external::file_digest(&exe))
            .unwrap_or_else(|_| "unknown".into())
    })
}

impl Producer {
    /// This program on `scenario`.
    ///
    /// # Errors
    /// A feature program file that cannot be read.
    pub(crate) fn of(scenario: &CheckedScenario) -> Result<Self> {
        let feature_programs = scenario
            .get()
            .features
            .external
            .iter()
            .map(|program| {
                let digest = evitrack::external::program_digest(program)
                    .with_context(|| format!("reading feature program {:?}", program.command))?;
                Ok((program.command.clone(), digest))
            })
            .collect::<Result<_>>()?;
        Ok(Self {
            evitrack: env!("CARGO_PKG_VERSION").into(),
            build: build_digest().into(),
            feature_programs,
        })
    }

    /// As written into `producer.json`.
    pub(crate) fn to_json(&self) -> String {
        serde_json::to_string_pretty(self).unwrap_or_default() + "\n"
    }

    /// Why results written by `earlier` (`None`: no `producer.json`, or one this version cannot
    /// read) are not this program's; `None` when they are.
    pub(crate) fn differs_from(&self, earlier: Option<&Producer>) -> Option<String> {
        let Some(earlier) = earlier else {
            return Some("written before runs recorded what produced them".into());
        };
        if self.build == "unknown" {
            return Some("this build's digest cannot be read".into());
        }
        if earlier.evitrack != self.evitrack {
            return Some(format!(
                "written by evitrack {}, this is {}",
                earlier.evitrack, self.evitrack
            ));
        }
        if earlier.build != self.build {
            return Some("written by another build of evitrack".into());
        }
        (earlier.feature_programs != self.feature_programs)
            .then(|| "a feature program changed".into())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn producer(build: &str, programs: &[(&str, &str)]) -> Producer {
        Producer {
            evitrack: "0.1.0".into(),
            build: build.into(),
            feature_programs: programs
                .iter()
                .map(|(c, d)| (vec![c.to_string()], d.to_string()))
                .collect(),
        }
    }

    #[test]
    fn only_the_same_build_and_programs_match() {
        let now = producer("b1", &[("f.py", "d1")]);
        assert_eq!(now.differs_from(Some(&now.clone())), None);
        assert!(now
            .differs_from(None)
            .unwrap()
            .contains("before runs recorded"));
        let other_build = producer("b2", &[("f.py", "d1")]);
        assert!(now
            .differs_from(Some(&other_build))
            .unwrap()
            .contains("another build"));
        let edited = producer("b1", &[("f.py", "d2")]);
        assert!(now
            .differs_from(Some(&edited))
            .unwrap()
            .contains("feature program"));
        let mut older = now.clone();
        older.evitrack = "0.0.9".into();
        assert!(now
            .differs_from(Some(&older))
            .unwrap()
            .contains("evitrack 0.0.9"));
        let unreadable = producer("unknown", &[]);
        assert!(unreadable.differs_from(Some(&unreadable.clone())).is_some());
        let text = now.to_json();
        assert_eq!(serde_json::from_str::<Producer>(&text).unwrap(), now);
    }
}
