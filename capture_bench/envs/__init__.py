"""The gymnasium environments: [`CaptureEnv`][capture_bench.envs.capture_env.CaptureEnv]
(one episode) and [`CaptureVectorEnv`][capture_bench.envs.vector_env.CaptureVectorEnv]
(N episodes stepped together)."""
