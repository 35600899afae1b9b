//! A training session, as one library call: the flag checks, the resume decision, reading (or waiting for) the
//! dataset, the robot-level split, the standardisation, the checkpoint's description, then the training loop. The
//! command line only turns flags into a [`Recipe`] and draws progress from a [`SessionObserver`].

use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::Duration;

use dynforge_dataset::examples::Examples;

use dynforge_dataset::cache::evidence::PhysicsSet;
use dynforge_dataset::cache::windows::CachedWindows;
use dynforge_dataset::cache::{CacheError, Loaded, Skipped};
use dynforge_dataset::evidence::{self, Draw, EvidenceError, draw_seed};
use dynforge_dataset::examples::ExampleRecord;
use dynforge_dataset::examples::corpus::Corpus;
use dynforge_dataset::examples::generated::{ExamplesError, PhysicsExamples, PhysicsSource};
use dynforge_dataset::features::JacobianFeatures;
use dynforge_dataset::normalize::{Standardizer, split_windows};
use dynforge_dataset::prepare::ModelKind;
use dynforge_dataset::split::SplitRule;
use dynforge_dataset::window::WindowSpec;
use dynforge_proto::NUM_LABELS;
use dynforge_recording::ReadError;
use dynforge_recording::dataset::{ShardFollower, dataset_robot, generator, shard_dir};

use super::recipe::Recipe;
use super::{Run, TrainError, TrainObserver, TrainSummary, resumable, train};
use crate::checkpoint::{Checkpoint, CheckpointError, PriorRecord};
use crate::model::NetworkConfig;

/// What differs between two example settings, as `generated robots per epoch 32768 -> 65536, real examples
/// trained on -> left out`.
fn examples_changed(was: &ExampleRecord, now: &ExampleRecord) -> String {
    let used = |real: bool| if real { "trained on" } else { "left out" };
    let mut changed = Vec::new();
    if was.generated_per_epoch != now.generated_per_epoch {
        changed.push(format!("generated robots per epoch {} -> {}", was.generated_per_epoch, now.generated_per_epoch));
    }
    if was.real != now.real {
        changed.push(format!("real examples {} -> {}", used(was.real), used(now.real)));
    }
    if was.noisy != now.noisy {
        changed.push(format!("noisy generated robots {} -> {}", was.noisy, now.noisy));
    }
    changed.join(", ")
}

/// Progress of a session beyond the training loop's.
pub trait SessionObserver: TrainObserver {
    /// `done` of `total` items of a preprocessing stage (`what`).
    fn preprocessing(&mut self, _what: &str, _done: usize, _total: usize) {}
}

impl SessionObserver for () {}

#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    #[error("{0}")]
    Setup(String),
    #[error(transparent)]
    Read(#[from] ReadError),
    #[error(transparent)]
    Evidence(#[from] EvidenceError),
    #[error(transparent)]
    Cache(#[from] CacheError),
    #[error(transparent)]
    Examples(#[from] ExamplesError),
    #[error(transparent)]
    Checkpoint(#[from] CheckpointError),
    #[error(transparent)]
    Train(#[from] TrainError),
    #[error("interrupted: the run is saved in {0}; continue it with --resume")]
    Interrupted(String),
}

/// What a session's data became: returned so that an evaluation right after training need not read them again.
pub enum Inputs {
    Windows(CachedWindows),
    Physics(PhysicsSet),
}

/// A finished session.
pub struct Trained {
    pub summary: TrainSummary,
    pub inputs: Inputs,
}

/// One training run.
pub struct Session<'a> {
    /// A `dynforge generate` directory.
    pub data: &'a Path,
    /// The checkpoint directory.
    pub out: &'a Path,
    /// Continue the run in `out` (a fresh start if there is none).
    pub resume: bool,
    /// Train while the dataset is generated (transformer).
    pub follow: bool,
    pub recipe: &'a Recipe,
    /// Set (e.g. by a signal handler) to checkpoint and stop at the next step.
    pub stop: &'a AtomicBool,
}

impl Session<'_> {
    pub fn run(&self, observer: &mut dyn SessionObserver) -> Result<Trained, SessionError> {
        let r = self.recipe;
        if !(r.validation > 0.0 && r.validation < 1.0) {
            return Err(SessionError::Setup(format!("--validation {} must be between 0 and 1", r.validation)));
        }
        if r.train.micro_batches == 0 || r.train.micro_batches > r.train.batch {
            return Err(SessionError::Setup(format!(
                "--micro-batches {} must be between 1 and --batch {}",
                r.train.micro_batches, r.train.batch
            )));
        }
        if r.window.len == 0 || r.window.stride == 0 || r.window.ssr == 0 {
            return Err(SessionError::Setup("--len, --stride and --ssr must be positive".into()));
        }
        if !r.window.is_valid() {
            return Err(SessionError::Setup(format!("--hop {} must divide --len {}", r.window.hop, r.window.len)));
        }
        if let Some(m) = dynforge_proto::manifest::Manifest::load(self.data).map_err(ReadError::from)?
            && let Some(family) = m.family
        {
            return Err(SessionError::Setup(format!(
                "{} is a robot's family (`generate --urdf`), labelled with its standard parameters; the estimators \
                 learn the generator's robots and their 38 labels. For a family drawn from the URDF's prior, \
                 `identify --spread {}` already gives the most probable values; `dynforge calibrate` uses the \
                 family to measure the spreads it reports on that robot",
                self.data.display(),
                family.spread
            )));
        }
        let (previous, resume) = self.previous(observer)?;
        match previous.as_ref().map_or(r.model.kind, |c| match c.model {
            NetworkConfig::Transformer(_) => ModelKind::Transformer,
            NetworkConfig::Physics(_) => ModelKind::Physics,
        }) {
            ModelKind::Transformer => self.transformer(previous, resume, observer),
            ModelKind::Physics => self.physics(previous, resume, observer),
        }
    }

    /// The run in `out` this session continues, if any, and whether it saved a state to resume from. Without --resume
    /// a run there is refused; with it, a run on other data is (its model would be replaced by one fitted to those),
    /// and one stopped before its first save (kill -9 or a full disk in epoch 0: a description and no state) is
    /// trained again from its start, with its settings.
    fn previous(&self, observer: &mut dyn SessionObserver) -> Result<(Option<Checkpoint>, bool), SessionError> {
        let out = self.out.display();
        let described = match Checkpoint::read(self.out) {
            Ok(c) => Some(c),
            // A resume state without its description: not to be overwritten by a new run.
            Err(e) if resumable(self.out) => return Err(e.into()),
            Err(_) => None,
        };
        let Some(c) = described else {
            if self.resume {
                observer.message(&format!("{out} holds no run to resume; starting a new one"));
            }
            return Ok((None, false));
        };
        if !self.resume {
            return Err(SessionError::Setup(format!(
                "{out} already holds a checkpoint: pass --resume to continue it, or choose another --out"
            )));
        }
        let data = std::fs::canonicalize(self.data).unwrap_or(self.data.to_path_buf()).display().to_string();
        if !c.dataset.is_empty() && c.dataset != data {
            return Err(SessionError::Setup(format!(
                "{out} was trained on {}, not on {data}: resume it with its own data, or train on {data} into another \
                 --out",
                c.dataset
            )));
        }
        if !resumable(self.out) {
            observer.message(&format!(
                "{out} stopped before its first save (no resume state): training it again from its start, with its \
                 settings"
            ));
            return Ok((Some(c), false));
        }
        Ok((Some(c), true))
    }

    fn training_run(&self, resume: bool) -> Run<'_> {
        Run { dir: self.out, config: &self.recipe.train, resume, stop: self.stop }
    }

    /// A resumed run keeps its split; a new one takes the recipe's.
    fn split(&self, previous: &Option<Checkpoint>) -> SplitRule {
        let r = self.recipe;
        previous
            .as_ref()
            .map_or(SplitRule { by: r.split, seed: r.train.seed, fraction: r.validation }, |c| c.split_rule())
    }

    fn stamp(&self, c: &mut Checkpoint, split: &SplitRule) {
        c.dataset = std::fs::canonicalize(self.data).unwrap_or(self.data.to_path_buf()).display().to_string();
        c.set_split(split);
    }

    fn finish(
        &self,
        summary: TrainSummary,
        inputs: Inputs,
        observer: &mut dyn SessionObserver,
    ) -> Result<Trained, SessionError> {
        if summary.interrupted {
            return Err(SessionError::Interrupted(self.out.display().to_string()));
        }
        observer.message(&format!(
            "{} after {} epochs; best epoch {} -> {}",
            if summary.stopped_early { "stopped early" } else { "finished" },
            summary.history.len(),
            summary.best_epoch,
            self.out.display()
        ));
        Ok(Trained { summary, inputs })
    }

    fn transformer(
        &self,
        previous: Option<Checkpoint>,
        resume: bool,
        observer: &mut dyn SessionObserver,
    ) -> Result<Trained, SessionError> {
        let spec = previous.as_ref().map_or(self.recipe.window, Checkpoint::window_spec);
        let split = self.split(&previous);
        let (windows, features, robot) = self.windows(&spec, observer)?;
        // After the first shard exists, so that `shards/` of a generate directory is what is followed.
        let mut follower = ShardFollower::new(&shard_dir(self.data));
        let mut corpus =
            Corpus { windows, train: Vec::new(), validation: Vec::new(), standardizer: Standardizer::fit_empty() };
        if self.follow {
            self.wait_for_both_splits(&mut corpus, &mut follower, &features, &split, observer)?;
        } else {
            (corpus.train, corpus.validation) = split_windows(&corpus.windows, &split);
        }
        let checkpoint = match previous {
            Some(c) => c,
            None => {
                let standardizer = Standardizer::fit(&corpus.windows, &corpus.train);
                let model = self.recipe.model.transformer(standardizer.columns.len(), spec.len);
                model.check().map_err(TrainError::from)?;
                let mut c =
                    Checkpoint::new(NetworkConfig::Transformer(model), &spec, &robot, Some(&features), &standardizer);
                self.stamp(&mut c, &split);
                c
            }
        };
        corpus.standardizer = checkpoint.standardizer();
        observer.message(&format!(
            "model: {}; {} training / {} validation windows",
            checkpoint.model.describe(),
            corpus.train.len(),
            corpus.validation.len()
        ));
        // Messages of the growth step wait for the observer's next call (both need it mutably).
        let notes = std::cell::RefCell::new(Vec::new());
        let mut grow = |c: &mut Corpus| self.grow(c, &mut follower, &features, &split, &notes);
        let grow: Option<&mut dyn FnMut(&mut Corpus)> = if self.follow { Some(&mut grow) } else { None };
        let mut relay = Relay { observer, notes: Some(&notes) };
        let summary = train(&mut corpus, grow, checkpoint, &self.training_run(resume), &mut relay)?;
        relay.flush();
        self.finish(summary, Inputs::Windows(corpus.windows), observer)
    }

    /// The dataset's windows (none yet when following a generation), its features and joint names.
    fn windows(
        &self,
        spec: &WindowSpec,
        observer: &mut dyn SessionObserver,
    ) -> Result<(CachedWindows, JacobianFeatures, dynforge_robot::Model), SessionError> {
        if self.follow {
            let robot = self.wait_for_robot(observer)?;
            return Ok((CachedWindows::new(*spec), JacobianFeatures::new(&robot), robot));
        }
        let robot = dataset_robot(self.data)?;
        let features = JacobianFeatures::new(&robot);
        // Training holds the cache in memory: one larger than the machine is refused before it is read.
        let file = dynforge_dataset::cache::windows::cache_path(self.data, spec, &features)?;
        if let Ok(meta) = std::fs::metadata(&file) {
            super::check_memory(meta.len() as u128, || format!("the window cache {}", file.display()))?;
        }
        let loaded = CachedWindows::load(self.data, spec, &features, None, |k, n| {
            observer.preprocessing("windows", k, n);
            !self.stop.load(Ordering::Relaxed)
        })?;
        let origin = origin(observer, &loaded);
        let w = loaded.cache;
        observer.message(&format!("{} windows of {} x {} values ({origin})", w.count(), spec.len, w.width));
        Ok((w, features, robot))
    }

    /// Adds the shards a followed generation writes until both splits have windows (the statistics need both).
    fn wait_for_both_splits(
        &self,
        corpus: &mut Corpus,
        follower: &mut ShardFollower,
        features: &JacobianFeatures,
        split: &SplitRule,
        observer: &mut dyn SessionObserver,
    ) -> Result<(), SessionError> {
        loop {
            let new = follower.poll().map_err(|e| self.listing(e))?;
            skip(observer, &corpus.add_shards(&new, features, split));
            if !corpus.train.is_empty() && !corpus.validation.is_empty() {
                return Ok(());
            }
            if self.stop.load(Ordering::Relaxed) {
                return Err(SessionError::Setup("interrupted while waiting for shards of both splits".into()));
            }
            std::thread::sleep(Duration::from_secs(2));
        }
    }

    /// Between epochs of a followed generation: the windows of the shards written since, with a note for the
    /// observer.
    fn grow(
        &self,
        c: &mut Corpus,
        follower: &mut ShardFollower,
        features: &JacobianFeatures,
        split: &SplitRule,
        notes: &std::cell::RefCell<Vec<String>>,
    ) {
        match follower.poll() {
            Ok(new) if !new.is_empty() => {
                let before = c.windows.count();
                let skipped = c.add_shards(&new, features, split);
                let mut n = notes.borrow_mut();
                n.extend(skipped.iter().map(|s| format!("warning: skipped {s}")));
                n.push(format!(
                    "follow: {} new shards, {} new windows ({} skipped)",
                    new.len(),
                    c.windows.count() - before,
                    skipped.len()
                ));
            }
            Ok(_) => {}
            Err(e) => notes.borrow_mut().push(format!("warning: listing {}: {e}", self.data.display())),
        }
    }

    fn physics(
        &self,
        previous: Option<Checkpoint>,
        resume: bool,
        observer: &mut dyn SessionObserver,
    ) -> Result<Trained, SessionError> {
        if self.follow {
            return Err(SessionError::Setup(
                "--follow trains the transformer only: the physics estimator's statistics need the whole dataset \
                 (train with --model physics once the generation is done)"
                    .into(),
            ));
        }
        let spec = previous.as_ref().map_or(self.recipe.window, Checkpoint::window_spec);
        let split = self.split(&previous);
        let (generator_cfg, seed) = generator(self.data)?.ok_or_else(|| {
            EvidenceError::Generator(format!(
                "{} has no run manifest to take the generator configuration from (train the physics estimator on a \
                 `dynforge generate` directory, or use --model transformer)",
                self.data.display()
            ))
        })?;
        let prior = match previous.as_ref().and_then(Checkpoint::parameter_prior) {
            Some(p) => p,
            None => {
                observer
                    .message(&format!("fitting the generator's parameter prior to {} robots", evidence::PRIOR_ROBOTS));
                evidence::generator_prior(&generator_cfg, seed)?
            }
        };
        let loaded = PhysicsSet::load(self.data, &spec, &prior, None, |k, n| {
            observer.preprocessing("physics", k, n);
            !self.stop.load(Ordering::Relaxed)
        })?;
        let origin = origin(observer, &loaded);
        let set = loaded.cache;
        observer.message(&format!(
            "physics of {} windows and {} recordings in {} prior coordinates ({origin})",
            set.windows.len(),
            set.recordings.len(),
            prior.rank(),
        ));
        let record = ExampleRecord {
            generated_per_epoch: self.recipe.generated_per_epoch,
            real: !self.recipe.generated_only,
            noisy: self.recipe.noisy,
        };
        let source =
            PhysicsSource { generator: generator_cfg, seed: draw_seed(seed, Draw::Synthetic), examples: record };
        let mut examples = PhysicsExamples::new(&set, prior, &split, source)?;
        // An epoch's generated robots are drawn and held at once (twice, while they are gathered).
        let per_robot = (examples.shape()[1] * 4 + NUM_LABELS * 8 + 8) as u128;
        let generated = self.recipe.generated_per_epoch;
        super::check_memory(2 * generated as u128 * per_robot, || {
            format!("--generated {generated}: an epoch's robots")
        })?;
        let checkpoint = self.physics_checkpoint(previous, &examples, &spec, &split, record, observer)?;
        observer.message(&format!(
            "model: {}; {} real training examples (windows, recordings, robots) + {} generated robots per epoch, {} \
             validation windows",
            checkpoint.model.describe(),
            examples.real(),
            self.recipe.generated_per_epoch,
            examples.validation_len()
        ));
        let mut relay = Relay { observer, notes: None };
        let summary = train(&mut examples, None, checkpoint, &self.training_run(resume), &mut relay)?;
        self.finish(summary, Inputs::Physics(set), observer)
    }

    /// The checkpoint a physics run continues (saying what changed in its examples) or starts.
    fn physics_checkpoint(
        &self,
        previous: Option<Checkpoint>,
        examples: &PhysicsExamples,
        spec: &WindowSpec,
        split: &SplitRule,
        record: ExampleRecord,
        observer: &mut dyn SessionObserver,
    ) -> Result<Checkpoint, SessionError> {
        let mut checkpoint = match previous {
            Some(c) => {
                if let Some(was) = c.examples.filter(|was| *was != record) {
                    observer.message(&format!("examples changed: {} from here", examples_changed(&was, &record)));
                }
                c
            }
            None => {
                let model = self.recipe.model.physics(examples.shape()[1]);
                model.check().map_err(TrainError::from)?;
                let robot = dataset_robot(self.data)?;
                let std = examples.standardizer().clone();
                let mut c = Checkpoint::new(NetworkConfig::Physics(model), spec, &robot, None, &std);
                c.prior = Some(PriorRecord::new(examples.prior()));
                self.stamp(&mut c, split);
                c
            }
        };
        checkpoint.examples = Some(record);
        Ok(checkpoint)
    }

    fn listing(&self, e: std::io::Error) -> SessionError {
        SessionError::Read(ReadError::Content { file: self.data.display().to_string(), problem: e.to_string() })
    }

    /// Waits until the dataset has a readable shard and returns its robot (`follow`, started with the generation).
    fn wait_for_robot(&self, observer: &mut dyn SessionObserver) -> Result<dynforge_robot::Model, SessionError> {
        let mut told = false;
        loop {
            match dataset_robot(self.data) {
                Ok(m) => return Ok(m),
                Err(e) if self.stop.load(Ordering::Relaxed) => {
                    return Err(SessionError::Setup(format!("interrupted while waiting for shards: {e}")));
                }
                Err(_) => {
                    if !told {
                        observer.message(&format!("waiting for the first shard in {} ...", self.data.display()));
                        told = true;
                    }
                    std::thread::sleep(Duration::from_secs(2));
                }
            }
        }
    }
}

/// Where a cache came from, as the session's message says it; the shards skipped on the way are warned of.
fn origin<C>(observer: &mut dyn SessionObserver, loaded: &Loaded<C>) -> String {
    skip(observer, &loaded.skipped);
    match (&loaded.unwritten, loaded.hit) {
        (_, true) => "from the cache".into(),
        (Some(why), false) => format!("built; {why}"),
        (None, false) => "built and cached".into(),
    }
}

fn skip(observer: &mut dyn SessionObserver, skipped: &[Skipped]) {
    for s in skipped {
        observer.message(&format!("warning: skipped {s}"));
    }
}

/// Passes the training loop's progress on to the session's observer, with the notes the follower left since.
struct Relay<'a, 'b> {
    observer: &'a mut (dyn SessionObserver + 'b),
    notes: Option<&'a std::cell::RefCell<Vec<String>>>,
}

impl Relay<'_, '_> {
    fn flush(&mut self) {
        if let Some(n) = self.notes {
            for text in n.borrow_mut().drain(..) {
                self.observer.message(&text);
            }
        }
    }
}

impl TrainObserver for Relay<'_, '_> {
    fn step(&mut self, epoch: usize, batch: usize, batches: usize, loss: f64) {
        self.flush();
        self.observer.step(epoch, batch, batches, loss);
    }

    fn epoch(&mut self, m: &dynforge_dataset::metrics::EpochMetrics, best: bool) {
        self.flush();
        self.observer.epoch(m, best);
    }

    fn message(&mut self, text: &str) {
        self.flush();
        self.observer.message(text);
    }
}
