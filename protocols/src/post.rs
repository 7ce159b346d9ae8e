//! Posts: each turns the Toolpath IR into the units one kind of device takes, and writes them
//! as the file `machlink plan -o` makes (G-code text, a DST or JEF file, motion-block text).

use crate::program::{Program, Unit};
use offset_core::Toolpath;
use std::sync::Arc;

/// Why a post could not make or write a program.
#[derive(Debug, thiserror::Error)]
#[error("{message}")]
pub struct PostError {
    /// The post's name.
    pub post: String,
    /// One sentence, naming the move or unit at fault.
    pub message: String,
}

impl PostError {
    pub fn new(post: &str, message: impl std::fmt::Display) -> PostError {
        PostError {
            post: post.to_string(),
            message: message.to_string(),
        }
    }
}

/// A post for units of type `Unit`.
pub trait Post: Send + Sync + 'static {
    type Unit: Unit;
    /// The name `--post` takes (`grbl`, `dst`, …).
    fn name(&self) -> &'static str;
    /// One line for help texts and docs.
    fn about(&self) -> &'static str;
    /// The file extension `plan` suggests for its output, without the dot.
    fn extension(&self) -> &'static str;
    /// The program's units for a tool path.
    fn units(&self, tp: &Toolpath) -> Result<Vec<Self::Unit>, PostError>;
    /// The units as the file `plan -o` writes; `label` names the job (a DST header's label).
    fn file(&self, units: &[Self::Unit], label: &str) -> Result<Vec<u8>, PostError>;
}

/// A post of any unit type, as registries hold it.
pub trait AnyPost: Send + Sync + 'static {
    fn name(&self) -> &'static str;
    fn about(&self) -> &'static str;
    fn extension(&self) -> &'static str;
    /// The program for a tool path.
    fn program(&self, tp: &Toolpath) -> Result<Program, PostError>;
    /// A program this post made, as its file.
    fn file(&self, program: &Program, label: &str) -> Result<Vec<u8>, PostError>;
}

impl<P: Post> AnyPost for P {
    fn name(&self) -> &'static str {
        Post::name(self)
    }
    fn about(&self) -> &'static str {
        Post::about(self)
    }
    fn extension(&self) -> &'static str {
        Post::extension(self)
    }
    fn program(&self, tp: &Toolpath) -> Result<Program, PostError> {
        Ok(Program::new(Post::name(self), self.units(tp)?))
    }
    fn file(&self, program: &Program, label: &str) -> Result<Vec<u8>, PostError> {
        // a program in memory (what a post just made) is written from its own units; one
        // read page by page is gathered first
        if let Some(units) = program.units::<P::Unit>() {
            return Post::file(self, units, label);
        }
        let units = program.view::<P::Unit>().ok_or_else(|| {
            PostError::new(
                Post::name(self),
                format!(
                    "a program made by the {} post cannot be written as a {} file",
                    program.post(),
                    Post::name(self)
                ),
            )
        })?;
        let units = units
            .to_vec()
            .map_err(|e| PostError::new(Post::name(self), e.to_string()))?;
        Post::file(self, &units, label)
    }
}

/// The posts whose units are `U`, as a kind lists the ones it accepts.
pub type PostFor<U> = Arc<dyn Post<Unit = U>>;

/// Text units written one per line, each ended by a newline.
pub fn lines_file<U: std::fmt::Display>(units: &[U]) -> Vec<u8> {
    use std::fmt::Write;
    // written in place (`to_string` made a string per unit)
    let mut out = String::with_capacity(32 * units.len());
    for u in units {
        write!(out, "{u}").expect("a String takes any text");
        out.push('\n');
    }
    out.into_bytes()
}
