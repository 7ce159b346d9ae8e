//! Programs: what a post makes from a tool path and a link sends, unit by unit.
//!
//! Each kind of device acknowledges its own kind of unit (a G-code line, a stitch record, a
//! motion block, …). A [`Program`] holds the units of one post whatever their type, so the
//! daemon can store, count and show them without knowing it; only the link of the kind that
//! made them reads them back as their own type ([`Program::view`]).
//!
//! A program is held in memory (what a post just made) or read from somewhere else page by
//! page ([`UnitPages`]: the daemon's store), so that a long program (a G-code file of
//! millions of lines) costs a link a page or two of memory, never its length. Links read
//! either through the same [`Units`] view.

use serde::de::DeserializeOwned;
use serde::Serialize;
use std::any::{Any, TypeId};
use std::fmt::Debug;
use std::ops::Range;
use std::sync::{Arc, Mutex};

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

/// Where a long program's units are kept: pages of `page_len()` units each (the last may
/// be shorter), each a JSON array of the units, read one at a time.
pub trait UnitPages: Debug + Send + Sync {
    /// Units in all.
    fn len(&self) -> usize;
    fn is_empty(&self) -> bool {
        self.len() == 0
    }
    /// Units per page.
    fn page_len(&self) -> usize;
    /// Page `k` (units `k * page_len ..`), a JSON array.
    fn page(&self, k: usize) -> Result<Vec<u8>, String>;
}

/// A program's units could not be read (their page is missing or broken).
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("cannot read the program's unit {unit}: {why}")]
pub struct UnitsError {
    /// The unit asked for (0-based).
    pub unit: usize,
    pub why: String,
}

/// The pages kept in memory at a time: the one being streamed and the one before it (the
/// device may still answer for its units).
const PAGES_KEPT: usize = 2;

/// Units of type `U` read page by page from [`UnitPages`], keeping [`PAGES_KEPT`] pages.
pub struct Paged<U> {
    pages: Arc<dyn UnitPages>,
    kept: Mutex<Vec<(usize, Arc<Vec<U>>)>>,
}

impl<U> Debug for Paged<U> {
    fn fmt(&self, f: &mut std::fmt::Formatter) -> std::fmt::Result {
        f.debug_struct("Paged").field("pages", &self.pages).finish()
    }
}

impl<U: Unit> Paged<U> {
    pub fn new(pages: Arc<dyn UnitPages>) -> Paged<U> {
        Paged {
            pages,
            kept: Mutex::new(Vec::new()),
        }
    }

    fn len(&self) -> usize {
        self.pages.len()
    }

    /// The page holding unit `i`, and `i`'s place in it.
    fn page_of(&self, i: usize) -> Result<(Arc<Vec<U>>, usize), UnitsError> {
        let per = self.pages.page_len().max(1);
        let (k, at) = (i / per, i % per);
        let mut kept = self.kept.lock().unwrap_or_else(|p| p.into_inner());
        if let Some((_, p)) = kept.iter().find(|(n, _)| *n == k) {
            return Ok((p.clone(), at));
        }
        let err = |why: String| UnitsError { unit: i, why };
        let bytes = self.pages.page(k).map_err(err)?;
        let page: Vec<U> = serde_json::from_slice(&bytes)
            .map_err(|e| err(format!("page {k} is not a list of units: {e}")))?;
        let want = per.min(self.len() - k * per);
        if page.len() != want {
            return Err(err(format!(
                "page {k} holds {} units instead of {want}",
                page.len()
            )));
        }
        let page = Arc::new(page);
        if kept.len() == PAGES_KEPT {
            kept.remove(0);
        }
        kept.push((k, page.clone()));
        Ok((page, at))
    }
}

/// A program's units as type `U`, wherever they are kept: what a link streams from. Cheap
/// to copy; [`Units::get`] and [`Units::iter`] read a page at a time from a paged program.
pub struct Units<'a, U> {
    held: Held<'a, U>,
}

enum Held<'a, U> {
    Slice(&'a [U]),
    Paged(&'a Paged<U>),
}

impl<U> Clone for Units<'_, U> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<U> Copy for Units<'_, U> {}
impl<U> Clone for Held<'_, U> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<U> Copy for Held<'_, U> {}

impl<'a, U> From<&'a [U]> for Units<'a, U> {
    fn from(s: &'a [U]) -> Self {
        Units {
            held: Held::Slice(s),
        }
    }
}

impl<'a, U> From<&'a Vec<U>> for Units<'a, U> {
    fn from(s: &'a Vec<U>) -> Self {
        Units {
            held: Held::Slice(s.as_slice()),
        }
    }
}

impl<'a, U: Unit> From<&'a Paged<U>> for Units<'a, U> {
    fn from(p: &'a Paged<U>) -> Self {
        Units {
            held: Held::Paged(p),
        }
    }
}

impl<'a, U: Unit> Units<'a, U> {
    pub fn len(&self) -> usize {
        match self.held {
            Held::Slice(s) => s.len(),
            Held::Paged(p) => p.len(),
        }
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// Unit `i`; an error past the end or when its page cannot be read.
    pub fn get(&self, i: usize) -> Result<U, UnitsError> {
        match self.held {
            Held::Slice(s) => s.get(i).cloned().ok_or_else(|| UnitsError {
                unit: i,
                why: format!("the program has {} units", s.len()),
            }),
            Held::Paged(p) => {
                if i >= p.len() {
                    return Err(UnitsError {
                        unit: i,
                        why: format!("the program has {} units", p.len()),
                    });
                }
                let (page, at) = p.page_of(i)?;
                Ok(page[at].clone())
            }
        }
    }

    /// Units `range` in order (clipped to the program), each read as its page comes.
    pub fn iter(&self, range: Range<usize>) -> impl Iterator<Item = Result<U, UnitsError>> + 'a {
        let this = *self;
        let end = range.end.min(self.len());
        (range.start.min(end)..end).map(move |i| this.get(i))
    }

    /// Every unit, in memory: for devices that take the whole program at once (a pattern
    /// upload) or links that have not learnt to read pages.
    pub fn to_vec(&self) -> Result<Vec<U>, UnitsError> {
        match self.held {
            Held::Slice(s) => Ok(s.to_vec()),
            Held::Paged(_) => self.iter(0..self.len()).collect(),
        }
    }
}

/// The units of a program, whatever their type.
trait Kept: Any + Debug + Send + Sync {
    fn len(&self) -> usize;
    fn unit_type(&self) -> TypeId;
    fn describe(&self, i: usize) -> Option<String>;
    /// Units `range` as a JSON array.
    fn to_json(&self, range: Range<usize>) -> Result<String, String>;
    fn as_any(&self) -> &dyn Any;
}

impl<U: Unit> Kept for Vec<U> {
    fn len(&self) -> usize {
        Vec::len(self)
    }
    fn unit_type(&self) -> TypeId {
        TypeId::of::<U>()
    }
    fn describe(&self, i: usize) -> Option<String> {
        self.get(i).map(Unit::describe)
    }
    fn to_json(&self, range: Range<usize>) -> Result<String, String> {
        let end = range.end.min(self.len());
        serde_json::to_string(&self[range.start.min(end)..end]).map_err(|e| e.to_string())
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

impl<U: Unit> Kept for Paged<U> {
    fn len(&self) -> usize {
        Paged::len(self)
    }
    fn unit_type(&self) -> TypeId {
        TypeId::of::<U>()
    }
    fn describe(&self, i: usize) -> Option<String> {
        Units::from(self).get(i).ok().map(|u| u.describe())
    }
    fn to_json(&self, range: Range<usize>) -> Result<String, String> {
        let units: Vec<U> = Units::from(self)
            .iter(range)
            .collect::<Result<_, _>>()
            .map_err(|e| e.to_string())?;
        serde_json::to_string(&units).map_err(|e| e.to_string())
    }
    fn as_any(&self) -> &dyn Any {
        self
    }
}

/// An ordered list of units that the device acknowledges one by one, and the post that made
/// them. Progress is counted in units; the last acknowledged unit is where a resume starts.
/// Cheap to clone (the units are shared).
#[derive(Clone, Debug)]
pub struct Program {
    post: String,
    units: Arc<dyn Kept>,
}

impl PartialEq for Program {
    fn eq(&self, other: &Program) -> bool {
        if self.post != other.post
            || self.len() != other.len()
            || self.units.unit_type() != other.units.unit_type()
        {
            return false;
        }
        let all = 0..self.len();
        matches!(
            (self.units.to_json(all.clone()), other.units.to_json(all)),
            (Ok(a), Ok(b)) if a == b
        )
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

    /// A program whose units of type `U` stay in `pages`, read a page at a time.
    pub fn paged<U: Unit>(post: impl Into<String>, pages: Arc<dyn UnitPages>) -> Program {
        Program {
            post: post.into(),
            units: Arc::new(Paged::<U>::new(pages)),
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

    /// The units as type `U`, wherever they are kept; None when they are of another type
    /// (a program made for another kind of device).
    pub fn view<U: Unit>(&self) -> Option<Units<'_, U>> {
        let any = self.units.as_any();
        if let Some(v) = any.downcast_ref::<Vec<U>>() {
            return Some(v.into());
        }
        any.downcast_ref::<Paged<U>>().map(Units::from)
    }

    /// The units as a slice of type `U`, for a program held in memory (what a post just
    /// made); None for one of another type or one read page by page ([`Program::view`]
    /// reads both).
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

    /// The units as a JSON array.
    pub fn to_json(&self) -> Result<String, serde_json::Error> {
        self.page_json(0..self.len())
    }

    /// Units `range` as a JSON array (a page for the job store).
    pub fn page_json(&self, range: Range<usize>) -> Result<String, serde_json::Error> {
        self.units
            .to_json(range)
            .map_err(<serde_json::Error as serde::ser::Error>::custom)
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

    /// Pages of `per` lines in memory, counting the reads, one page broken on purpose.
    #[derive(Debug)]
    struct Book {
        lines: Vec<String>,
        per: usize,
        reads: std::sync::atomic::AtomicUsize,
        broken: Option<usize>,
    }

    impl UnitPages for Book {
        fn len(&self) -> usize {
            self.lines.len()
        }
        fn page_len(&self) -> usize {
            self.per
        }
        fn page(&self, k: usize) -> Result<Vec<u8>, String> {
            self.reads
                .fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            if self.broken == Some(k) {
                return Ok(b"[1, 2".to_vec());
            }
            let end = ((k + 1) * self.per).min(self.lines.len());
            Ok(serde_json::to_vec(&self.lines[k * self.per..end]).unwrap())
        }
    }

    fn book(n: usize, per: usize, broken: Option<usize>) -> Arc<Book> {
        Arc::new(Book {
            lines: (0..n).map(|i| format!("G1 X{i}")).collect(),
            per,
            reads: Default::default(),
            broken,
        })
    }

    #[test]
    fn a_paged_program_reads_each_page_once_in_a_pass_and_equals_the_same_units_in_memory() {
        let b = book(2500, 1000, None);
        let p = Program::paged::<String>("gcode-file", b.clone());
        assert_eq!(p.len(), 2500);
        let v = p.view::<String>().unwrap();
        let all: Vec<String> = v.iter(0..v.len()).map(Result::unwrap).collect();
        assert_eq!(all, b.lines, "every line in order");
        assert_eq!(
            b.reads.load(std::sync::atomic::Ordering::Relaxed),
            3,
            "one read per page in a pass"
        );
        // the device answers for a line of the page before: it is still kept
        assert_eq!(v.get(1999).unwrap(), "G1 X1999");
        assert_eq!(b.reads.load(std::sync::atomic::Ordering::Relaxed), 3);
        assert_eq!(p, Program::new("gcode-file", b.lines.clone()));
        assert_eq!(p.describe_unit(2499), "G1 X2499");
        assert!(p.units::<String>().is_none(), "no slice of a paged program");
        assert!(p.view::<crate::sewing::StitchRecord>().is_none());
        assert!(v.get(2500).is_err(), "past the end");
    }

    #[test]
    fn a_broken_page_is_an_error_naming_the_unit_never_a_panic() {
        let p = Program::paged::<String>("gcode-file", book(30, 10, Some(1)));
        let v = p.view::<String>().unwrap();
        assert_eq!(v.get(9).unwrap(), "G1 X9");
        let e = v.get(12).unwrap_err();
        assert_eq!(e.unit, 12);
        assert!(e.to_string().contains("page 1"), "{e}");
        assert!(v.to_vec().is_err());
    }
}
