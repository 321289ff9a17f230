"""`make demo`: the main job on the shipped sample frames (grows with every issue)."""

import sys


def main() -> int:
    print("dropvision demo: pipeline under construction")
    return 0


if __name__ == "__main__":
    sys.exit(main())
