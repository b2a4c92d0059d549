"""`python -m incipient_slip.graph.launch FILE.yaml ...`: the same as the `launch` command."""
import sys

from incipient_slip.graph.launch import main

sys.exit(main())
