"""``python -m abb_robot.protocol_table``: print README.md's protocol tables from :mod:`abb_robot.protocol`."""

from abb_robot.protocol import main

if __name__ == "__main__":
    main()
