import sys

from flatlab_lerobot.collect import main

sys.exit(main())
