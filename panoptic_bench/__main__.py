from panoptic_bench.cli import main

raise SystemExit(main())
