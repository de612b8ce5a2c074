"""What each ``drqn-jax`` command says of itself in ``--help``."""

REPORT_DOC = """Regenerate every block between '<!-- results:NAME -->' and '<!-- /results -->'
in the documents from section NAME of the results file (drqn-jax study --results FILE
--section NAME writes it): its table, comparisons, command and wall time, so that no
document retypes a number."""
TRAIN_DOC = """Train the DRQN of a config; writes config.toml, metrics.csv, checkpoints,
evaluation.json and results.md to the run directory. Ctrl-C (or SIGTERM) saves a
checkpoint and exits with status 130; --resume continues bit-identically."""
EVALUATE_DOC = """Evaluate a run directory's DRQN (or a sweep's or study's trained agent,
OUT/agents/run-NNNN) or a built-in agent greedily on the evaluation key and print the SPEC §8
metrics. --set changes the episodes, not the agent: e.g. --set env.id=... evaluates it among
other pedestrians, --seed 0 on a study's episodes."""
REPRODUCE_DOC = """Evaluate the trained agent shipped with drqn_jax (--agent headline, its
provenance printed) and the paper's rule-based agent on evaluate.episodes episodes each
(1000), sweep the rule-based family's frontier on the same episodes, and print the paper's
Table III beside ours with each agent's margin to the frontier, the verdict on the paper's
claim, the safety/speed figure's path and the wall time; no training. --train trains the
agent again first (its config, or --config; an estimate of the training time on this
device comes first) and evaluates that one. Writes evaluation.json, results.md and
safety_speed.png to the run directory."""
REPLAY_DOC = """Record episodes of a run directory's greedy DRQN (with its four Q-values per
step) or of a built-in agent as a rerun recording: the map, the ego, the pedestrians coloured by
behaviour, the four grid channels, speed, action, reward and TTC on the timeline "step". Episode
i is episode i of `evaluate` (the config's evaluation key). View it with: rerun PATH"""
SWEEP_DOC = """Run every point of a sweep file: points that share shapes train together in
compiled jit(vmap) calls, the runs sharded over all local devices, as many per call as the
memory plan allows; each run is evaluated on the same episodes. Writes results.md and
results.csv (mean, std, 95 % t-interval and IQM across seeds per setting) and runs.json
(every run), and every run's trained agent in OUT/agents/run-NNNN (for evaluate and
replay). Ctrl-C saves checkpoints (status 130); --resume continues, also a sweep
file given more points after the saved ones (more seeds). With several
processes each trains its slice of the runs and process 0 writes the results."""
STUDY_DOC = """Train every config for seeds 0 … N-1 (one sweep over run.seed per
config, in OUT/<config>/), evaluate every run greedily on the same episodes (the first
seed's evaluation key), evaluate the rule-based agent on them, and write OUT/study.md
(the paper's Table III beside ours: collision-free % with a 95 % interval across seeds,
speed, distance, goal %, collisions per km), OUT/study.json, and the training curves
(average reward and steps per episode, mean and min-max over seeds) as OUT/curves.png
and OUT/curves.rrd. Each run's trained agent is OUT/<config>/agents/run-NNNN; --eval-envs
evaluates them among other pedestrians too (one more row per env). Ctrl-C saves checkpoints
(status 130); running the same command again continues the study, and with a larger
--seeds adds the new seeds to it; --eval-envs on a finished study only evaluates. With
--runs-store (by default with --results), an interrupted study keeps its finished runs in
a file of their own, and the same command in a fresh --out (a new clone) trains only the
others; the results file holds the finished study's rows only."""
FRONTIER_DOC = """Sweep the rule-based agent over its parameters (v_max from 1 km/h to the
speed limit, lookahead, horizon, corridor margin) on the config's evaluation episodes, as
one compiled program, and keep its Pareto-efficient points (collision-free rate against
average speed): the frontier every agent's margin is measured against. Then play the
privileged planner (it sees the true state and plays the simulator forward: a ceiling,
never a learner's competitor) at each speed cap. Prints both, with the wall time of each;
writes OUT/frontier.json (every swept point) and OUT/frontier.png, and with --results the
points as a section of the results file."""
EXPORT_DOC = """Write the agent of a finished run directory as OUT/config.toml and
OUT/agent.npz (its parameters alone, no training state: a few MB, with the config's
training hash) and OUT/provenance.json (the training command, episodes, env steps,
gradient steps and wall time, the commit and device that trained it, and this machine:
a sweep's run, OUT/agents/run-NNNN, names its own commit and device; a drqn-jax train
run is taken to have trained here, so export it where it trained). evaluate and
replay read OUT like a run directory; a directory under drqn_jax/agents/trained/NAME
is shipped with the package as --agent NAME."""
BENCH_DOC = """Run the benchmark suite of benchmarks/ (a clone of the repository is
needed): each benchmark prints a Markdown table with the machine it ran on, and
--out DIR writes DIR/NAME.json and DIR/NAME.md. 'all' runs every benchmark with
the options --repeats, --out and --quick passed on to each. 'quick' prints
env steps/s and training throughput of one config (options --config, --set,
--num-envs, --steps, --iterations) and needs no clone."""
