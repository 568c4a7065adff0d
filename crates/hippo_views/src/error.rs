use thiserror::Error;

/// Everything that can go wrong when configuring view cells or giving them a template.
/// Messages say what was wrong and what to do about it.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ViewError {
    #[error("invalid view-cell parameter `{name}` = {value}: {why}")]
    BadParameter {
        name: &'static str,
        value: String,
        why: String,
    },
    #[error(
        "template has {got} values, expected {expected} (height {height_px} × width {width_px}); \
         build templates with the same parameters as the view cells"
    )]
    BadTemplateSize {
        got: usize,
        expected: usize,
        height_px: usize,
        width_px: usize,
    },
    #[error(
        "template value at row {row}, column {col} is not finite ({value}); check the input image"
    )]
    NonFinite { row: usize, col: usize, value: f32 },
    #[error("view cell {id} does not exist (there are {count})")]
    UnknownCell { id: usize, count: usize },
    #[error(
        "candidate {position} is view cell {id}, which does not exist (there are {count}, so ids are \
         below {count}); restrict the search to ids of stored cells"
    )]
    UnknownCandidate {
        id: usize,
        position: usize,
        count: usize,
    },
}
