//! Model families.

pub mod diffsheg;
