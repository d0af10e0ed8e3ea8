use super::*;

const WIDTH: usize = 100;
const HEIGHT: usize = 80;

/// A disc of 10 px whose centre moves 5 px per mm of pose, as the robot's end-effector does.
fn disc(at: [f64; 2]) -> Vec<bool> {
    let centre = [30.0 + 5.0 * at[0], 25.0 + 5.0 * at[1]];
    (0..HEIGHT)
        .flat_map(|y| (0..WIDTH).map(move |x| (x, y)))
        .map(|(x, y)| (x as f64 + 0.5 - centre[0]).hypot(y as f64 + 0.5 - centre[1]) <= 10.0)
        .collect()
}

fn mismatch(a: &[bool], b: &[bool]) -> usize {
    a.iter().zip(b).filter(|(x, y)| x != y).count()
}

fn mesh(spacing: f64, nodes: usize) -> SampleSilhouettes {
    let poses = (0..nodes).flat_map(|j| (0..nodes).map(move |i| [i as f64, j as f64]));
    let poses: Vec<[f64; 2]> = poses.map(|p| [p[0] * spacing, p[1] * spacing]).collect();
    SampleSilhouettes::new(WIDTH, HEIGHT, &poses, |&p| Some((p, disc(p))), 1).expect("a mesh")
}

#[test]
fn the_distance_transform_is_exact() {
    // A scatter of pixels, every distance checked against all of them.
    let (w, h) = (23, 17);
    let mask: Vec<bool> = (0..w * h).map(|i| (i * 7919) % 53 < 3).collect();
    let inside: Vec<(usize, usize)> = (0..w * h)
        .filter(|&i| mask[i])
        .map(|i| (i % w, i / w))
        .collect();
    assert!(inside.len() > 5);
    let found = squared_distances(&mask, w, h, true);
    for (i, &d) in found.iter().enumerate() {
        let (x, y) = ((i % w) as f64, (i / w) as f64);
        let brute = (inside.iter())
            .map(|&(a, b)| (x - a as f64).powi(2) + (y - b as f64).powi(2))
            .fold(f64::INFINITY, f64::min);
        assert_eq!(d, brute, "pixel {i}");
    }
    // No pixel of the other side: infinite everywhere.
    let none = squared_distances(&vec![false; w * h], w, h, true);
    assert!(none.iter().all(|d| d.is_infinite()));
}

#[test]
fn the_field_is_positive_inside_and_its_edge_is_the_silhouettes() {
    let mask = disc([1.0, 1.0]);
    let field = signed_distances(&mask, WIDTH, HEIGHT);
    for (&m, &f) in mask.iter().zip(&field) {
        assert_eq!(m, f > 0, "{f}");
    }
}

#[test]
fn between_samples_the_prediction_follows_the_pose_far_closer_than_the_nearest_sample() {
    let samples = mesh(1.0, 7);
    assert_eq!(samples.len(), 49);
    for at in [[2.37, 3.61], [0.5, 0.5], [4.9, 1.2], [5.5, 5.5]] {
        let predicted = samples.predict(at).expect("a finite pose");
        let nearest = disc([at[0].round(), at[1].round()]);
        let (ours, theirs) = (
            mismatch(&predicted, &disc(at)),
            mismatch(&nearest, &disc(at)),
        );
        // Within the mismatch of a disc 0.2 mm (1 px) away, so such an error shows.
        let off = mismatch(&predicted, &disc([at[0] + 0.2, at[1]]));
        assert!(
            ours <= 30 && ours * 2 < theirs && off > ours + 10,
            "{at:?}: {ours} against the nearest sample's {theirs}, 0.2 mm off {off}"
        );
    }
    // Sparser samples predict worse.
    let sparse = mesh(2.0, 4);
    let at = [2.9, 3.1];
    let (dense, coarse) = (samples.predict(at).unwrap(), sparse.predict(at).unwrap());
    assert!(mismatch(&dense, &disc(at)) < mismatch(&coarse, &disc(at)));
}

#[test]
fn samples_on_a_line_and_undefined_inputs_are_handled() {
    // Three samples on a line fix no plane: the kernel-weighted mean, still a silhouette.
    let line = [0.0, 1.0, 2.0].map(|x| ([x, 0.0], disc([x, 0.0])));
    let given = |sample: &([f64; 2], Vec<bool>)| Some(sample.clone());
    let samples = SampleSilhouettes::new(WIDTH, HEIGHT, &line, given, 1).expect("three samples");
    let predicted = samples.predict([1.0, 0.0]).expect("a finite pose");
    assert!(mismatch(&predicted, &disc([1.0, 0.0])) < 60);
    assert!(samples.predict([f64::NAN, 0.0]).is_none());
    // Fewer than three samples, or a pose that is not finite, fix nothing.
    let two = [0.0, 1.0].map(|x| ([x, 0.0], disc([x, 0.0])));
    assert!(SampleSilhouettes::new(WIDTH, HEIGHT, &two, given, 1).is_none());
    let bad = [0.0, 1.0, f64::INFINITY].map(|x| ([x, 0.0], disc([0.0, 0.0])));
    assert!(SampleSilhouettes::new(WIDTH, HEIGHT, &bad, given, 1).is_none());
    // Frames without a silhouette are skipped: three of five leave a plane.
    let some = |&x: &f64| (x < 3.0).then(|| ([x, 0.0], disc([x, 0.0])));
    let kept = SampleSilhouettes::new(WIDTH, HEIGHT, &[0.0, 1.0, 2.0, 3.0, 4.0], some, 2);
    assert_eq!(kept.expect("three kept").len(), 3);
}

#[test]
fn the_packed_prediction_is_the_whole_frame_sum_bit_for_bit() {
    // A frame whose pixel count is not a multiple of 64 (851), so the last word is partial.
    let (w, h) = (37, 23);
    let blob = |at: [f64; 2]| -> Vec<bool> {
        (0..w * h)
            .map(|i| {
                ((i % w) as f64 - 15.0 - 3.0 * at[0]).hypot((i / w) as f64 - 10.0 - 2.0 * at[1])
                    < 6.0
            })
            .collect()
    };
    let poses = (0..5).flat_map(|j| (0..5).map(move |i| [i as f64 * 0.7, j as f64 * 0.7]));
    let poses: Vec<[f64; 2]> = poses.collect();
    let samples = SampleSilhouettes::new(w, h, &poses, |&p| Some((p, blob(p))), 1).expect("a mesh");
    for at in [[0.3, 1.9], [1.4, 1.4], [2.8, 0.05], [-0.4, 3.1]] {
        // The sum over the whole frame at once, as the prediction was first written.
        let mut field = vec![0.0f32; w * h];
        for (n, weight) in samples.weights(at).unwrap() {
            for (value, &sample) in field.iter_mut().zip(&samples.fields[n]) {
                *value += weight as f32 * f32::from(sample);
            }
        }
        let words = samples.predict_packed(at).unwrap();
        assert_eq!(words.len(), (w * h).div_ceil(64));
        for (i, v) in field.iter().enumerate() {
            assert_eq!(
                words[i / 64] >> (i % 64) & 1 == 1,
                *v > 0.0,
                "{at:?} pixel {i}"
            );
        }
        // Bits past the last pixel stay clear.
        assert_eq!(words[words.len() - 1] >> ((w * h) % 64), 0);
        assert_eq!(
            samples.predict(at).unwrap(),
            field.iter().map(|v| *v > 0.0).collect::<Vec<_>>()
        );
    }
}

#[test]
fn two_threads_make_the_fields_of_one() {
    let poses: Vec<[f64; 2]> = (0..7)
        .flat_map(|j| (0..5).map(move |i| [i as f64, j as f64]))
        .collect();
    let made = |threads| {
        SampleSilhouettes::new(WIDTH, HEIGHT, &poses, |&p| Some((p, disc(p))), threads)
            .expect("a mesh")
    };
    let (one, two) = (made(1), made(2));
    assert_eq!(one.poses, two.poses);
    assert_eq!(one.fields, two.fields);
    assert_eq!(on_threads(2, &[3, 1, 4], |x| x * 2), vec![6, 2, 8]);
    assert_eq!(on_threads(2, &[] as &[i32], |x| x * 2), Vec::<i32>::new());
}
