//! Unit tests of the feature configuration and the feature set.

use super::*;

#[test]
fn default_is_six_size_functions_and_preset_adds_barycentre() {
    let six = FeatureConfig::default().check().unwrap();
    assert_eq!(
        six.names(),
        (0..6).map(|i| format!("size_line{i}")).collect::<Vec<_>>()
    );
    let eight = FeatureConfig::with_barycentre().check().unwrap();
    assert_eq!(eight.len(), 8);
    assert_eq!(&eight.names()[6..], &["barycentre_x", "barycentre_y"]);
}

#[test]
fn bad_settings_are_rejected() {
    let mut c = FeatureConfig::default();
    c.size_functions.window = [5.0, 5.0];
    assert!(matches!(c.check(), Err(FeatureError::BadWindow { .. })));
    let mut c = FeatureConfig::default();
    c.size_functions.lines = 0;
    assert!(matches!(
        c.check(),
        Err(FeatureError::BadLines { lines: 0 })
    ));
    let mut c = FeatureConfig::default();
    c.size_functions.mean = MeanMethod::Table;
    c.size_functions.table_grid = 1;
    assert!(matches!(c.check(), Err(FeatureError::BadGrid { grid: 1 })));
    c.size_functions.table_grid = 5000;
    assert!(matches!(
        c.check(),
        Err(FeatureError::BadGrid { grid: 5000 })
    ));
    let mut c = FeatureConfig::default();
    c.size_functions.enabled = false;
    assert!(matches!(c.check(), Err(FeatureError::NoFeatures)));
    let mut c = FeatureConfig::default();
    c.silhouette.min_contrast = f64::NAN;
    assert!(matches!(c.check(), Err(FeatureError::BadContrast { .. })));
}

#[test]
fn config_round_trips_through_toml_and_rejects_typos() {
    let c = FeatureConfig::with_barycentre();
    let text = toml::to_string(&c).unwrap();
    let back: FeatureConfig = toml::from_str(&text).unwrap();
    assert_eq!(back, c);
    let partial: FeatureConfig = toml::from_str(
        "[size_functions]\nlines = 4\nmean = \"table\"\n[silhouette]\nthreshold = { fixed = 90 }\n",
    )
    .unwrap();
    assert_eq!(partial.size_functions.lines, 4);
    assert_eq!(partial.silhouette.threshold, Threshold::Fixed(90));
    assert!(toml::from_str::<FeatureConfig>("[size_functions]\nline = 4\n").is_err());
    assert!(toml::from_str::<FeatureConfig>("colour = 1\n").is_err());
}

#[test]
fn extraction_on_threads_gives_the_same_rows_in_order() {
    let set = FeatureConfig::with_barycentre().check().unwrap();
    let images: Vec<GrayImage> = (0..7)
        .map(|k| {
            let pose = [-6.0 + 2.0 * k as f64, 40.0 + 2.5 * k as f64];
            synthetic::rig_like_frame(pose, 2.0, k).unwrap()
        })
        .collect();
    let refs: Vec<&GrayImage> = images.iter().collect();
    let one = set.extract_batch(refs.iter().copied());
    assert!(one.iter().flatten().any(Option::is_some));
    for threads in [1, 2, 3, 16] {
        let mut calls = Vec::new();
        let rows = set.extract_on(&refs, threads, &mut |done, total| calls.push((done, total)));
        assert_eq!(rows, one, "{threads} threads");
        assert!(calls.windows(2).all(|w| w[0].0 < w[1].0), "{calls:?}");
        assert_eq!(calls.last(), Some(&(7, 7)), "{threads} threads");
    }
    assert!(set
        .extract_on(&[], 2, &mut |_, _| panic!("no frames"))
        .is_empty());
}

#[derive(Debug)]
struct Sloppy(&'static str, usize);

impl Feature for Sloppy {
    fn names(&self) -> Vec<String> {
        vec![self.0.to_string(); 1]
    }
    fn extract(&self, _: &GrayImage, out: &mut Vec<Option<f64>>) {
        out.extend(std::iter::repeat_n(Some(f64::NAN), self.1));
    }
}

#[test]
fn custom_features_are_padded_and_sanitised() {
    let set = FeatureSet::new(vec![Arc::new(Sloppy("a", 0)), Arc::new(Sloppy("b", 3))]).unwrap();
    let v = set.extract(&GrayImage::new(4, 4));
    assert_eq!(v, vec![None, None]);
    assert!(matches!(
        FeatureSet::new(vec![Arc::new(Sloppy("a", 1)), Arc::new(Sloppy("a", 1))]),
        Err(FeatureError::DuplicateName { .. })
    ));
    assert!(matches!(
        FeatureSet::new(vec![]),
        Err(FeatureError::NoFeatures)
    ));
}
