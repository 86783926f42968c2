from nurbsmotion.cli import main

raise SystemExit(main())
