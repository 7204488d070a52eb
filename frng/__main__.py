from frng.cli import main

if __name__ == "__main__":
    main()
