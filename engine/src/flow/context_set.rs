//! Unordered sets in the context (e.g. obstacle centres), seen by the conditioners in one
//! canonical order.
//!
//! A context `c = [a, e₁, …, e_n, b]` whose elements `e_j ∈ ℝˢ` form a set describes the
//! same task under every permutation `π` of the elements. Feeding the conditioners the
//! canonical context
//!
//! `κ(c) = [a, e_σ(1), …, e_σ(n), b]`, `σ` sorting the elements by their first entry,
//!
//! makes the flow invariant by construction, `f(z, κ(π c)) = f(z, κ(c))` for distinct
//! keys, so the conditioners see one ordering of the set instead of `n!` (and each slot a
//! narrower distribution: slot 1 is the element with the smallest key). `κ` is a
//! permutation of the entries, continuous except where two keys tie; for every context
//! `f(·, κ(c))` is still a bijection, so stability is untouched. Ties keep the given order
//! (a stable sort), the same in the trainer and the pure-Rust policy.

use serde::{Deserialize, Serialize};

/// `count` consecutive elements of `size` entries each, from context index `start`, that
/// form an unordered set.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
pub struct ContextSet {
    pub start: usize,
    pub count: usize,
    pub size: usize,
}

impl ContextSet {
    /// One past the set's last context index.
    pub fn end(&self) -> usize {
        self.start + self.count * self.size
    }

    /// Sorts the set's elements of `context` by their first entry, in place (stable;
    /// insertion sort: sets are small and this allocates nothing).
    pub fn canonicalise(&self, context: &mut [f64]) {
        let elements = &mut context[self.start..self.end()];
        let key = |elements: &[f64], j: usize| elements[j * self.size];
        for i in 1..self.count {
            let mut j = i;
            while j > 0 && key(elements, j - 1) > key(elements, j) {
                let (left, right) = elements.split_at_mut(j * self.size);
                left[(j - 1) * self.size..].swap_with_slice(&mut right[..self.size]);
                j -= 1;
            }
        }
    }
}

/// `κ(c)`: `context` with every set canonicalised.
pub fn canonicalise(sets: &[ContextSet], context: &mut [f64]) {
    for set in sets {
        set.canonicalise(context);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const OBSTACLES: ContextSet = ContextSet {
        start: 1,
        count: 3,
        size: 2,
    };

    #[test]
    fn every_permutation_gives_the_elements_sorted_by_key_and_keeps_the_rest() {
        let elements = [[0.3, -1.0], [-0.2, 5.0], [0.1, 2.0]];
        let sorted = [-0.2, 5.0, 0.1, 2.0, 0.3, -1.0];
        for p in [
            [0, 1, 2],
            [0, 2, 1],
            [1, 0, 2],
            [1, 2, 0],
            [2, 0, 1],
            [2, 1, 0],
        ] {
            let mut context = vec![9.0];
            context.extend(p.iter().flat_map(|&j| elements[j]));
            context.push(7.0);
            OBSTACLES.canonicalise(&mut context);
            assert_eq!(context[1..7], sorted, "permutation {p:?}");
            assert_eq!((context[0], context[7]), (9.0, 7.0));
        }
    }

    #[test]
    fn ties_keep_the_given_order() {
        let mut context = vec![0.0, 1.0, 2.0, 1.0, 3.0, 0.5, 4.0, 0.0];
        OBSTACLES.canonicalise(&mut context);
        assert_eq!(context, [0.0, 0.5, 4.0, 1.0, 2.0, 1.0, 3.0, 0.0]);
    }
}
