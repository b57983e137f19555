"""Running an evaluation: the leaderboard suites (`suites`, ``configs/suites/*.yaml``), agent
specs made agents (`agents_loading`: built-in, trained model, ``module:Class``), one episode to one
`EpisodeRecord` (`rollout`), many episodes serially, in processes or on Ray (`backends`), and an
evaluated episode played again as an animated GIF (`video`). Nothing here imports
`capture_bench.evaluation.reporting`."""
