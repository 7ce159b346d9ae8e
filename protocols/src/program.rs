//! Programs: what a post makes from a tool path and a link sends, unit by unit.
//!
//! Each kind of device acknowledges its own kind of unit (a G-code line, a stitch record, a
//! motion block, …). A [`Program`] holds the units of one post whatever their type, so the
//! daemon can store, count and show them without knowing it; only the link of the kind that
//! made them reads them back as their own type ([`Program::units`]).

use serde::de::DeserializeOwned;
use serde::Serialize;
use std::any::Any;
use std::fmt::Debug;
use std::sync::Arc;

/// One unit of a program: what the device acknowledges, counted for progress and resume.
pub trait Unit:
    Clone + Debug + PartialEq + Serialize + DeserializeOwned + Send + Sync + 'static
{
    /// The unit as an operator reads it in a message (a G-code line as it is).
    fn describe(&self) -> String;
}

/// A G-code line, without its line ending.
impl Unit for String {
    fn describe(&self) -> String {
        self.clone()
    }
}

/// The units of a program, whatever their type.
trait Units: Any + Debug + Send + Sync {
    fn len(&self) -> usize;
    fn describe(&self, i: usize) -> Option<String>;
    fn to_json(&self) -> Result<String, serde_json::Error>;
    fn as_any(&self) -> &dyn Any;
    fn same(&self, other: &dyn Units) -> bool;
}

impl<U: Unit> Units for Vec<U> {
    fn len(&self) -> usize {
        Vec::len(self)
    }
    fn describe(&self, i: usize) -> Option<String> {
        self.get(i).map(Unit::describe)
    }
    fn to_json(&self) -> Result<String, serde_json::Error> {
        serde_json::to_string(self)
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
    fn same(&self, other: &dyn Units) -> bool {
        other
            .as_any()
            .downcast_ref::<Vec<U>>()
            .is_some_and(|o| o == self)
    }
}

/// An ordered list of units that the device acknowledges one by one, and the post that made
/// them. Progress is counted in units; the last acknowledged unit is where a resume starts.
/// Cheap to clone (the units are shared).
#[derive(Clone, Debug)]
pub struct Program {
    post: String,
    units: Arc<dyn Units>,
}

impl PartialEq for Program {
    fn eq(&self, other: &Program) -> bool {
        self.post == other.post && self.units.same(other.units.as_ref())
    }
}

impl Program {
    /// A program of `units` made by the post named `post` (`grbl`, `dst`, `modbus`, … or
    /// `gcode-file` for a G-code file taken as it is).
    pub fn new<U: Unit>(post: impl Into<String>, units: Vec<U>) -> Program {
        Program {
            post: post.into(),
            units: Arc::new(units),
        }
    }

    /// Reads units stored with [`Program::to_json`] back as units of type `U`.
    pub fn from_json<U: Unit>(post: &str, json: &str) -> Result<Program, serde_json::Error> {
        let units: Vec<U> = serde_json::from_str(json)?;
        Ok(Program::new(post, units))
    }

    /// The post that made the program.
    pub fn post(&self) -> &str {
        &self.post
    }

    /// The units as type `U`; None when they are of another type (a program made for
    /// another kind of device).
    pub fn units<U: Unit>(&self) -> Option<&[U]> {
        self.units
            .as_any()
            .downcast_ref::<Vec<U>>()
            .map(Vec::as_slice)
    }

    /// How many units the program has.
    pub fn len(&self) -> usize {
        self.units.len()
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Unit `i` as text, for messages (a G-code line as it is); empty past the end.
    pub fn describe_unit(&self, i: usize) -> String {
        self.units.describe(i).unwrap_or_default()
    }

    /// The units as a JSON array, for the job store.
    pub fn to_json(&self) -> Result<String, serde_json::Error> {
        self.units.to_json()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn units_come_back_as_their_own_type_only() {
        let p = Program::new("grbl", vec!["G0 X1".to_string(), "G1 X2 F100".to_string()]);
        assert_eq!(p.len(), 2);
        assert_eq!(p.units::<String>().unwrap()[1], "G1 X2 F100");
        assert!(p.units::<crate::sewing::StitchRecord>().is_none());
        assert_eq!(p.describe_unit(0), "G0 X1");
        assert_eq!(p.describe_unit(5), "");
        let back = Program::from_json::<String>("grbl", &p.to_json().unwrap()).unwrap();
        assert_eq!(back, p);
        assert_ne!(Program::new("linuxcnc", vec!["G0 X1".to_string()]), p);
    }
}
