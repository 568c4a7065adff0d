use thiserror::Error;

/// Everything that can go wrong when configuring view cells or giving them a template.
/// Messages say what was wrong and what to do about it.
#[derive(Debug, Error, Clone, PartialEq)]
pub enum ViewError {
    /// A parameter outside its range (the shape every core crate uses for parameter errors).
    #[error("invalid view-cell parameter `{name}` = {value}: {why}")]
    BadParameter {
        /// The parameter, as the config names it.
        name: &'static str,
        /// Its value as given.
        value: String,
        /// What it must be.
        why: String,
    },
    /// A template of another size than the cells'.
    #[error(
        "template has {got} values, expected {expected} (height {height_px} × width {width_px}); \
         build templates with the same parameters as the view cells"
    )]
    BadTemplateSize {
        /// Its number of values.
        got: usize,
        /// `height_px · width_px`.
        expected: usize,
        /// The cells' template height.
        height_px: usize,
        /// The cells' template width.
        width_px: usize,
    },
    /// A NaN or infinity in a template.
    #[error(
        "template value at row {row}, column {col} is not finite ({value}); check the input image"
    )]
    NonFinite {
        /// Its row.
        row: usize,
        /// Its column.
        col: usize,
        /// The value.
        value: f32,
    },
    /// A cell id that was never given out.
    #[error("view cell {id} does not exist (there are {count})")]
    UnknownCell {
        /// The id.
        id: usize,
        /// How many cells there are.
        count: usize,
    },
    /// A candidate id that was never given out.
    #[error(
        "candidate {position} is view cell {id}, which does not exist (there are {count}, so ids are \
         below {count}); restrict the search to ids of stored cells"
    )]
    UnknownCandidate {
        /// The id.
        id: usize,
        /// Its position in the candidate list.
        position: usize,
        /// How many cells there are.
        count: usize,
    },
    #[error(
        "no training descriptors: a vocabulary needs the ORB descriptors of at least one image"
    )]
    /// `Vocabulary::train` was given no descriptors at all.
    NoTrainingData,
    #[error("vocabulary file is unusable: {why}")]
    /// A vocabulary file failed a check (header, length, checksum or tree structure).
    BadVocabulary {
        /// Which check, and what was found.
        why: String,
    },
}
