from eskin.cli import main

raise SystemExit(main())
