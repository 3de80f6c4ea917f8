"""`python -m bcbench.cli ...` (torchrun and the background study scripts start bcbench this way)."""

from bcbench.cli.main import main

raise SystemExit(main())
