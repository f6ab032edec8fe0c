"""Scale-out on Ray: every (protocol, seed) as its own Ray task, and random search with Ray Tune.

`seal sweep FILE... [--seeds 0-4]` sends each (protocol, seed) pair to Ray as one task that calls
`seal.run.runner.run_seed`, so every trial writes exactly the run directory `seal run` writes, all
seeds of a protocol under one group. `seal sweep FILE --search` gives Ray Tune the protocol's
`[search]` table as its param_space: Tune draws the configs (a searcher seeded by [search].seed,
so the same table always tries the same configs) and runs them (optionally stopping weak ones
early with ASHA); its ResultGrid is ranked and the best resolved config written as a TOML file
ready for `seal run`.

Ray is optional (the `ray` extra): it is imported inside the functions that need it, never at
module import, so `seal run` and the protocol layer never load it.

On disk, a sweep is a directory holding `sweep.json` (what was asked, every trial and its status),
`trials.{csv,md}` and `tables/` (the `seal report` tables of the finished runs)::

    one protocol:      <out>/<protocol>/<group-id>/        sweep.json, seed-<n>/, tables/
    several:           <out>/sweeps/<sweep-id>/            sweep.json, tables/ (groups as above)
    search:            <out>/<protocol>/search-<id>/       sweep.json, sample-<k>/seed-<n>/,
                                                           search.{csv,md}, best.toml

Fault tolerance: a trial that raises (e.g. training diverged) is recorded with its error and the
others go on. `--resume SWEEP_DIR` re-reads sweep.json: trials whose run directory is finished
(provenance.json has an end_time) are kept as they are, started ones continue from their last
checkpoint, and the rest start afresh. A search's resume lets Tune draw the same samples again;
the kept ones only report their evaluations.

Modules: `grid` (the sweep of (protocol, seed) pairs), `search` (the Tune search) and `samples`
(its param space and samples), `trials` (one trial: its record, running it, reading its run
directory), `manifest` (the sweep directory: sweep.json, saved configs, `SweepResult`), `tables`
(ranking and the trials tables) and `ray_session` (the Ray connection and [resources]). The
[sweep] and [search] config tables are `seal.sweep.config_tables`.
"""
