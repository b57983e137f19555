"""The gymnasium environments: :class:`CaptureEnv` (one episode) and
:class:`CaptureVectorEnv` (N episodes stepped together)."""
