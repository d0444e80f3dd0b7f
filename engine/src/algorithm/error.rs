//! Errors of the algorithms and the input checks they share.

use thiserror::Error;

use crate::math::{DMatrix, Real};

#[derive(Clone, Debug, Error, PartialEq)]
pub enum DynamicsError {
    #[error("{quantity} has {actual} entries, expected {expected}")]
    Dimension {
        quantity: &'static str,
        expected: usize,
        actual: usize,
    },
    #[error(
        "{quantity} buffer is {actual_rows}×{actual_cols}, expected {expected_rows}×{expected_cols}"
    )]
    Shape {
        quantity: &'static str,
        expected_rows: usize,
        expected_cols: usize,
        actual_rows: usize,
        actual_cols: usize,
    },
    #[error("{quantity}[{index}] is not finite")]
    NonFinite {
        quantity: &'static str,
        index: usize,
    },
    #[error("frame {index} does not exist (the robot has {count} frames)")]
    NoSuchFrame { index: usize, count: usize },
    #[error("no frame named `{name}`; frames: {}", known.join(", "))]
    NoFrameNamed { name: String, known: Vec<String> },
    #[error("link {index} does not exist (the robot has {count} movable links)")]
    NoSuchLink { index: usize, count: usize },
    #[error(
        "the mass matrix is not positive definite: movable joint {joint} (counted from 0 \
         along the chain) moves no mass or inertia that the joints before it do not already \
         (e.g. its link's mass lies on its axis with no rotational inertia)"
    )]
    NotPositiveDefinite { joint: usize },
}

/// Checks the length of a vector (e.g. an output buffer).
pub(crate) fn check_len(
    quantity: &'static str,
    actual: usize,
    expected: usize,
) -> Result<(), DynamicsError> {
    if actual == expected {
        Ok(())
    } else {
        Err(DynamicsError::Dimension {
            quantity,
            expected,
            actual,
        })
    }
}

/// Checks that `values` has `expected` finite entries.
pub(crate) fn check_vector(
    quantity: &'static str,
    values: &[Real],
    expected: usize,
) -> Result<(), DynamicsError> {
    check_len(quantity, values.len(), expected)?;
    match values.iter().position(|x| !x.is_finite()) {
        Some(index) => Err(DynamicsError::NonFinite { quantity, index }),
        None => Ok(()),
    }
}

/// Checks that an output buffer is `rows × cols`.
pub(crate) fn check_matrix_shape(
    quantity: &'static str,
    matrix: &DMatrix,
    rows: usize,
    cols: usize,
) -> Result<(), DynamicsError> {
    if matrix.shape() == (rows, cols) {
        Ok(())
    } else {
        Err(DynamicsError::Shape {
            quantity,
            expected_rows: rows,
            expected_cols: cols,
            actual_rows: matrix.nrows(),
            actual_cols: matrix.ncols(),
        })
    }
}
