from swarm_sitl.cli import main

raise SystemExit(main())
