from mrsph.cli import main

raise SystemExit(main())
