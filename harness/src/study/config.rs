//! The study's configurations: the base, each knob swept alone around it, a few joint
//! settings, and the baselines, each with the database variant it needs.

use super::*;
use precompute::{BuildConfig, Profile};
use psf_db::PsfModel;
use spreadlet::pipeline::{ClassifyOptions, Integrator};
use spreadlet::synth::SynthOptions;

/// Database settings a configuration needs (each distinct one is a database of its own).
#[derive(Clone, Debug, PartialEq)]
pub(super) struct DbVariant {
    pub(super) budget: f32,
    /// PSF count relative to the profile's (the runtime's thin-lens count for thin-lens).
    pub(super) psf_scale: f32,
    pub(super) prefilter: bool,
    pub(super) dense_ratio: f32,
    /// No fast track at all: every PSF stored sparse and kept sparse by conditioning.
    pub(super) sparse_only: bool,
}

impl Default for DbVariant {
    fn default() -> Self {
        let base = BuildConfig::new(PsfModel::ThinLens, Profile::Test);
        Self {
            budget: base.spreadlet_budget,
            psf_scale: 1.0,
            prefilter: base.prefilter,
            dense_ratio: base.dense_ratio,
            sparse_only: false,
        }
    }
}

impl DbVariant {
    pub(super) fn key(&self) -> String {
        format!(
            "b{} s{} p{} d{} o{}",
            self.budget, self.psf_scale, self.prefilter, self.dense_ratio, self.sparse_only
        )
    }

    pub(super) fn apply(&self, mut cfg: BuildConfig) -> BuildConfig {
        cfg.spreadlet_budget = self.budget;
        cfg.prefilter = self.prefilter;
        cfg.dense_ratio = self.dense_ratio;
        if self.sparse_only {
            cfg = spreadlet::baseline::sparse_build_config(&cfg);
        }
        if self.psf_scale != 1.0 {
            let base = cfg
                .psf_count
                .unwrap_or_else(|| cfg.profile.spec(cfg.model).psf_count);
            cfg.psf_count = Some(((base as f32 * self.psf_scale).round() as u32).max(2));
        }
        cfg
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(super) enum Method {
    Spreadlet,
    Dense,
    Filter,
}

impl Method {
    pub(super) fn name(self) -> &'static str {
        match self {
            Method::Spreadlet => "spreadlet",
            Method::Dense => "dense",
            Method::Filter => "filter",
        }
    }
}

/// One configuration to run.
#[derive(Clone, Debug)]
pub(super) struct Config {
    pub(super) method: Method,
    pub(super) knob: String,
    pub(super) value: String,
    pub(super) db: DbVariant,
    pub(super) layers: u32,
    pub(super) soft_layers: Option<f32>,
    pub(super) integrator: Integrator,
    pub(super) gpu: bool,
}

impl Config {
    pub(super) fn base() -> Self {
        Config {
            method: Method::Spreadlet,
            knob: "base".into(),
            value: "-".into(),
            db: DbVariant::default(),
            layers: 8,
            soft_layers: Some(1.0),
            integrator: Integrator::Exact,
            gpu: false,
        }
    }

    /// What decides the result (the knob's name does not).
    pub(super) fn key(&self) -> String {
        format!(
            "{:?} {} l{} s{:?} {:?} g{}",
            self.method,
            self.db.key(),
            self.layers,
            self.soft_layers,
            self.integrator,
            self.gpu
        )
    }

    pub(super) fn with(
        &self,
        knob: &str,
        value: impl ToString,
        f: impl FnOnce(&mut Config),
    ) -> Config {
        let mut c = self.clone();
        c.knob = knob.into();
        c.value = value.to_string();
        f(&mut c);
        c
    }

    pub(super) fn synth_options(&self) -> SynthOptions {
        SynthOptions {
            classify: ClassifyOptions {
                layers: self.layers,
                soft_layers: self.soft_layers,
                ..ClassifyOptions::default()
            },
            integrator: self.integrator,
            ..SynthOptions::default()
        }
    }
}

pub(super) fn integrator_name(i: Integrator) -> &'static str {
    match i {
        Integrator::Pyramid => "pyramid",
        Integrator::Exact => "exact",
    }
}

/// The configurations of a study, in the order they run.
pub(super) fn configurations(options: &StudyOptions, gpu: bool) -> Vec<Config> {
    let base = Config::base();
    let mut v = vec![base.clone()];
    // Values of budget, PSF-count scale, layers, soft layering, fast-track ratio.
    type Sweeps = (Vec<f32>, Vec<f32>, Vec<u32>, Vec<f32>, Vec<f32>);
    let (budgets, scales, layers, softs, ratios): Sweeps = if options.tiny {
        (vec![0.5], vec![], vec![1], vec![], vec![])
    } else if options.full {
        (
            vec![0.25, 0.5, 1.0, 2.0, 4.0],
            vec![0.5, 1.0, 2.0, 4.0],
            vec![1, 2, 4, 8, 16],
            vec![0.0, 0.25, 0.5, 1.0],
            vec![0.1, 0.25, 0.5, 1.0, 2.0],
        )
    } else {
        (
            vec![0.5, 1.0, 2.0],
            vec![0.5, 1.0, 2.0],
            vec![1, 2, 4, 8],
            vec![0.0, 0.5, 1.0],
            vec![0.25, 0.5, 1.0],
        )
    };
    // The database knobs act on the spreadlets: swept with the fast track off (every PSF
    // sparse), where they decide every record.
    let sparse = base.with("fast_track", "off", |c| c.db.sparse_only = true);
    for b in &budgets {
        v.push(sparse.with("budget", b, |c| c.db.budget = *b));
    }
    for s in &scales {
        v.push(sparse.with("psf_samples", format!("x{s}"), |c| c.db.psf_scale = *s));
    }
    if !options.tiny {
        for p in [true, false] {
            v.push(sparse.with("prefilter", if p { "on" } else { "off" }, |c| {
                c.db.prefilter = p
            }));
        }
    }
    for r in &ratios {
        v.push(base.with("fast_track", r, |c| c.db.dense_ratio = *r));
    }
    // The speed end as shipped (fast track on): fewer spreadlets and the pyramid.
    if !options.tiny {
        for b in [0.5f32, 1.0] {
            v.push(base.with("budget_pyramid", b, |c| {
                c.db.budget = b;
                c.integrator = Integrator::Pyramid;
            }));
        }
    }
    v.push(sparse.clone());
    for l in &layers {
        v.push(base.with("layers", l, |c| c.layers = *l));
    }
    for s in &softs {
        v.push(base.with("soft_layers", s, |c| {
            c.soft_layers = (*s > 0.0).then_some(*s)
        }));
    }
    if !options.tiny {
        for i in [Integrator::Pyramid, Integrator::Exact] {
            v.push(base.with("integration", integrator_name(i), |c| c.integrator = i));
        }
    }
    v.push(base.with("backend", "cpu", |_| {}));
    if gpu {
        v.push(base.with("backend", "gpu", |c| c.gpu = true));
    }
    // Baselines: the same layering and compositing, with every PSF dense.
    let dense = base.with("baseline", "dense", |c| {
        c.method = Method::Dense;
        c.db.dense_ratio = 0.0;
    });
    v.push(dense.clone());
    if gpu {
        v.push(dense.with("baseline", "dense-gpu", |c| c.gpu = true));
        v.push(dense.with("baseline", "filter-gpu", |c| {
            c.method = Method::Filter;
            c.gpu = true;
        }));
    }
    v.push(dense.with("baseline", "filter", |c| c.method = Method::Filter));
    if options.full {
        for l in [1, 2, 4] {
            v.push(dense.with("baseline", format!("dense-layers-{l}"), |c| c.layers = l));
        }
    }
    // Jointly.
    if !options.tiny {
        let (jb, jl, ji, js): (Vec<f32>, Vec<u32>, Vec<Integrator>, Vec<f32>) = if options.full {
            (
                vec![0.5, 1.0, 2.0],
                vec![1, 2, 4, 8],
                vec![Integrator::Pyramid, Integrator::Exact],
                vec![0.5, 1.0, 2.0],
            )
        } else {
            (
                vec![0.5, 1.0, 2.0],
                vec![2, 8],
                vec![Integrator::Pyramid, Integrator::Exact],
                vec![1.0],
            )
        };
        for b in &jb {
            for l in &jl {
                for i in &ji {
                    for s in &js {
                        let value = format!(
                            "budget={b};layers={l};integration={};psf_samples=x{s}",
                            integrator_name(*i)
                        );
                        v.push(sparse.with("joint", value, |c| {
                            c.db.budget = *b;
                            c.layers = *l;
                            c.integrator = *i;
                            c.db.psf_scale = *s;
                        }));
                    }
                }
            }
        }
    }
    v
}
