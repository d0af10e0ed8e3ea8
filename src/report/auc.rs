//! The detection figure: area under the ROC curve of a method's detection scores against
//! "corrupted".

use super::FrameRecord;

/// Area under the ROC curve of the records' detection scores against "corrupted" (Mann–Whitney,
/// ties count one half); `None` without any score or without both classes.
///
/// A frame without a score counts as +∞: a method that cannot estimate a frame (the GP with a
/// feature missing) ranks it as the most suspicious, so its AUC on such faults says only that it
/// gave up on those frames. Scores are ordered by `f64::total_cmp`, so a NaN (which no writer
/// lets out) ranks above +∞ instead of breaking the walk.
pub fn detection_auc(records: &[FrameRecord]) -> Option<f64> {
    if records.iter().all(|r| r.detection_score.is_none()) {
        return None;
    }
    let score = |r: &FrameRecord| r.detection_score.unwrap_or(f64::INFINITY);
    let scored: Vec<(f64, bool)> = records.iter().map(|r| (score(r), r.corrupted())).collect();
    auc(scored)
}

/// The ROC curve of the records' detection scores against "corrupted" (scores as in
/// [`detection_auc`]): (false positive rate, true positive rate) from the strictest threshold to
/// the loosest, tied scores taken together; `None` where [`detection_auc`] is `None`.
pub fn roc_curve(records: &[FrameRecord]) -> Option<Vec<(f64, f64)>> {
    detection_auc(records)?;
    let mut scored: Vec<(f64, bool)> = (records.iter())
        .map(|r| (r.detection_score.unwrap_or(f64::INFINITY), r.corrupted()))
        .collect();
    let positives = scored.iter().filter(|s| s.1).count() as f64;
    let negatives = scored.len() as f64 - positives;
    scored.sort_by(|a, b| b.0.total_cmp(&a.0));
    let mut curve = vec![(0.0, 0.0)];
    let (mut tp, mut fp) = (0usize, 0usize);
    for (i, (score, positive)) in scored.iter().enumerate() {
        if *positive {
            tp += 1;
        } else {
            fp += 1;
        }
        let tie_continues = scored
            .get(i + 1)
            .is_some_and(|next| next.0.total_cmp(score).is_eq());
        if !tie_continues {
            curve.push((fp as f64 / negatives, tp as f64 / positives));
        }
    }
    Some(curve)
}

/// The AUC of `(score, positive)` pairs.
fn auc(mut scored: Vec<(f64, bool)>) -> Option<f64> {
    let positives = scored.iter().filter(|s| s.1).count();
    let negatives = scored.len() - positives;
    if positives == 0 || negatives == 0 {
        return None;
    }
    // Walk the scores in order, tied runs sharing their ranks. Ties are found with the same
    // order as the sort: `==` is false for NaN, which would end a run at length 0.
    scored.sort_by(|a, b| a.0.total_cmp(&b.0));
    let mut wins = 0.0;
    let mut negatives_below = 0usize;
    let mut i = 0;
    while i < scored.len() {
        let j = i + scored[i..]
            .iter()
            .take_while(|s| s.0.total_cmp(&scored[i].0).is_eq())
            .count();
        let tied_neg = scored[i..j].iter().filter(|s| !s.1).count();
        let tied_pos = (j - i) - tied_neg;
        wins += tied_pos as f64 * (negatives_below as f64 + 0.5 * tied_neg as f64);
        negatives_below += tied_neg;
        i = j;
    }
    Some(wins / (positives * negatives) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::estimator::PoseEstimate;
    use crate::faults::FrameFaults;

    /// A record with this score, corrupted or clean.
    fn record(score: Option<f64>, corrupted: bool) -> FrameRecord {
        let estimate = PoseEstimate {
            detection_score: score,
            ..Default::default()
        };
        let faults = FrameFaults {
            faults: if corrupted { vec!["f".into()] } else { vec![] },
            changed: if corrupted { vec![0] } else { vec![] },
            dropped: false,
        };
        FrameRecord::new("m", "test0", 0, 0.0, None, &estimate, &["f".into()]).with_faults(faults)
    }

    #[test]
    fn roc_runs_from_corner_to_corner_and_its_area_is_the_auc() {
        let records: Vec<FrameRecord> = [(5.0, true), (4.0, false), (3.0, true), (1.0, false)]
            .iter()
            .map(|&(s, c)| record(Some(s), c))
            .collect();
        let curve = roc_curve(&records).unwrap();
        assert_eq!(curve.first(), Some(&(0.0, 0.0)));
        assert_eq!(curve.last(), Some(&(1.0, 1.0)));
        let area: f64 = (curve.windows(2))
            .map(|w| (w[1].0 - w[0].0) * 0.5 * (w[0].1 + w[1].1))
            .sum();
        assert!((area - detection_auc(&records).unwrap()).abs() < 1e-12);
        assert_eq!(area, 0.75);
        assert!(roc_curve(&records[..1]).is_none());
    }

    #[test]
    fn separated_scores_give_one_and_reversed_give_zero() {
        let s = [(1.0, false), (2.0, false), (3.0, true), (4.0, true)];
        assert_eq!(auc(s.to_vec()), Some(1.0));
        let flipped: Vec<_> = s.iter().map(|&(x, c)| (-x, c)).collect();
        assert_eq!(auc(flipped), Some(0.0));
    }

    #[test]
    fn ties_count_one_half() {
        // One positive tied with one of two negatives, above the other: (1 + 0.5) / 2.
        assert_eq!(
            auc(vec![(1.0, false), (2.0, false), (2.0, true)]),
            Some(0.75)
        );
        // Everything tied: chance.
        assert_eq!(auc(vec![(5.0, true), (5.0, false), (5.0, true)]), Some(0.5));
    }

    #[test]
    fn one_class_or_no_score_gives_none() {
        assert_eq!(auc(vec![(1.0, true), (2.0, true)]), None);
        let records = [record(None, true), record(None, false)];
        assert_eq!(detection_auc(&records), None);
    }

    #[test]
    fn a_missing_score_ranks_first() {
        // The corrupted frame has no score: +∞, above the clean frame's.
        let records = [record(Some(7.0), false), record(None, true)];
        assert_eq!(detection_auc(&records), Some(1.0));
        // Tied with an infinite clean score: one half.
        let records = [record(Some(f64::INFINITY), false), record(None, true)];
        assert_eq!(detection_auc(&records), Some(0.5));
    }

    #[test]
    fn a_nan_score_ends_and_ranks_above_infinity() {
        let s = vec![(f64::NAN, true), (f64::INFINITY, false), (f64::NAN, true)];
        assert_eq!(auc(s), Some(1.0));
    }
}
