//! Where a sequence breaks, in words a user can act on: the images left out of every model are
//! reported as runs of consecutive names that share a reason ("frame_000116.png … frame_000135.png
//! (20 images): …"), not one warning per image, and separate models are listed by the runs of
//! images each holds, which shows where the walk was cut (a corridor's turn, a blank wall).

use crate::warning::{code, Warning};

use super::Unregistered;

/// Runs are listed up to this many; the rest are counted.
const MAX_RUNS: usize = 6;

/// The runs `(first, last)` (inclusive indices into `names`) of consecutive names for which
/// `member` holds.
pub(super) fn runs(names: &[String], member: impl Fn(usize) -> bool) -> Vec<(usize, usize)> {
    let mut out: Vec<(usize, usize)> = Vec::new();
    for i in (0..names.len()).filter(|&i| member(i)) {
        match out.last_mut() {
            Some(r) if r.1 + 1 == i => r.1 = i,
            _ => out.push((i, i)),
        }
    }
    out
}

/// `a.png … b.png (n)`, or the one name.
fn run_text(names: &[String], (a, b): (usize, usize)) -> String {
    if a == b {
        names[a].clone()
    } else {
        format!("{} … {} ({})", names[a], names[b], b - a + 1)
    }
}

/// The runs in words, at most [`MAX_RUNS`] of them.
pub(super) fn runs_text(names: &[String], runs: &[(usize, usize)]) -> String {
    let mut parts: Vec<String> = runs
        .iter()
        .take(MAX_RUNS)
        .map(|&r| run_text(names, r))
        .collect();
    if runs.len() > MAX_RUNS {
        parts.push(format!("and {} more runs", runs.len() - MAX_RUNS));
    }
    parts.join(", ")
}

/// A reason with its figures taken out, so that "its tracks reach 0 3D points" and "… 14 3D
/// points" are one kind.
fn kind(reason: &str) -> String {
    let mut out = String::with_capacity(reason.len());
    for c in reason.chars() {
        let c = if c.is_ascii_digit() { '#' } else { c };
        if !(c == '#' && out.ends_with('#')) {
            out.push(c);
        }
    }
    out
}

/// One warning per run of consecutive images (in `names` order) left out for the same kind of
/// reason; the reason given is the first image's.
pub(super) fn unregistered_warnings(names: &[String], left: &[Unregistered]) -> Vec<Warning> {
    let reason_of = |i: usize| left.iter().find(|u| u.image == names[i]).map(|u| &u.reason);
    let mut out = Vec::new();
    let mut i = 0;
    while i < names.len() {
        let Some(first) = reason_of(i) else {
            i += 1;
            continue;
        };
        let k = kind(first);
        let mut j = i;
        while j + 1 < names.len() && reason_of(j + 1).is_some_and(|r| kind(r) == k) {
            j += 1;
        }
        let message = if i == j {
            format!("{}: not registered ({first})", names[i])
        } else {
            format!(
                "{}: {} images not registered ({first}, for {})",
                run_text(names, (i, j)),
                j - i + 1,
                names[i]
            )
        };
        out.push(Warning::new(code::UNREGISTERED, message));
        i = j + 1;
    }
    // Names the input does not list (none expected) keep their own warning.
    for u in left.iter().filter(|u| !names.contains(&u.image)) {
        out.push(Warning::new(
            code::UNREGISTERED,
            format!("{}: not registered ({})", u.image, u.reason),
        ));
    }
    out
}

/// The separate-models warning, with the runs of images each model holds.
pub(super) fn separate_models_warning(names: &[String], models: &[Vec<usize>]) -> Warning {
    let details: Vec<String> = models
        .iter()
        .enumerate()
        .map(|(k, m)| {
            let where_ = if k == 0 {
                "sparse/".to_string()
            } else {
                format!("sparse/models/{k}/")
            };
            format!(
                "{where_}: {} images: {}",
                m.len(),
                runs_text(names, &runs(names, |i| m.contains(&i)))
            )
        })
        .collect();
    Warning::new(
        code::SEPARATE_MODELS,
        format!(
            "the images form {} separate models; the largest is in sparse/, the others in sparse/models/ ({})",
            models.len(),
            details.join("; ")
        ),
    )
    .advice("add photos that link the pieces (overlapping views between them)")
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names(n: usize) -> Vec<String> {
        (0..n).map(|i| format!("f{i:02}.png")).collect()
    }

    #[test]
    fn consecutive_images_left_out_for_one_kind_of_reason_make_one_warning() {
        let n = names(10);
        let left: Vec<Unregistered> = [
            (2, "its tracks reach 0 3D points, need 20"),
            (3, "its tracks reach 14 3D points, need 20"),
            (4, "its tracks reach 3 3D points, need 20"),
            (5, "no features"),
            (8, "no features"),
        ]
        .iter()
        .map(|&(i, r)| Unregistered {
            image: n[i].clone(),
            reason: r.into(),
        })
        .collect();
        let w = unregistered_warnings(&n, &left);
        let msgs: Vec<&str> = w.iter().map(|w| w.message.as_str()).collect();
        assert_eq!(
            msgs,
            [
                "f02.png … f04.png (3): 3 images not registered (its tracks reach 0 3D points, need 20, for f02.png)",
                "f05.png: not registered (no features)",
                "f08.png: not registered (no features)",
            ]
        );
        let sep = separate_models_warning(&n, &[vec![0, 1, 6, 7, 9], vec![2, 3]]);
        assert!(
            sep.message.contains(
                "sparse/: 5 images: f00.png … f01.png (2), f06.png … f07.png (2), f09.png; sparse/models/1/: 2 images: f02.png … f03.png (2)"
            ),
            "{}",
            sep.message
        );
    }
}
